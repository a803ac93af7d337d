"""Real PX4 firmware (SITL, the wall-clock build) for the embedded world: where it is
installed, which instance numbers are free, the parameters of a mocap lab, and one
running instance as a child process.

A PX4 SITL instance ``n`` (docs/reference/px4-offboard.md §5) connects as a TCP client to
its simulator at 127.0.0.1:4560+n, sends its offboard/API MAVLink link from UDP 14580+n
to 14540+n and keeps a lock file and a socket per instance in /tmp, machine-wide; it writes
parameters and logs into its working directory. Parameters are set before boot through the
hook PX4's start-up script provides for them: a ``px4-rc.params`` found first on PATH is
sourced after the airframe defaults and before any module starts, so EKF2 boots with the
vision-only set-up (changing its height source while running left a height offset).
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import fcntl
import hashlib
import logging
import os
import resource
import shutil
import signal
import socket
import tarfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)

PX4_DIR_ENV = "UAVBAR_PX4_DIR"
BUILD_NAME = "px4-sitl-v1.15.4-nolockstep"
ARCHIVE_SHA256 = "c3461f39dde3377dfa9739bb4e73d0583634cb72a01618cca3816019b9076276"
REPOSITORY = Path(__file__).resolve().parents[1]
# Where the project's shared firmware archive sits next to a checkout (CI and lab machines
# get it there; nothing is downloaded).
ARCHIVE_CANDIDATES = (REPOSITORY.parent / "shared" / "px4" / f"{BUILD_NAME}.tar.xz",)
CACHE_DIR = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "uavbar-supervisor"
AIRFRAME = "10016_none_iris"  # PX4's quadrotor driven by an external simulator
SIMULATOR_PORT = 4560
OFFBOARD_LOCAL_PORT = 14580  # PX4's end of the offboard/API link
OFFBOARD_REMOTE_PORT = 14540  # where it sends: the supervisor listens here
MAX_INSTANCE = 9  # above 9 PX4 sends every instance's offboard link to 14549
STOP_TIMEOUT_S = 5.0
PR_SET_PDEATHSIG = 1
PR_CAPBSET_DROP = 24
CAP_SYS_NICE = 23
PX4_PRIORITY = 4  # SCHED_FIFO: below the world that feeds it (5) and the flight process (10)


class FirmwareError(RuntimeError):
    """No usable PX4 installation, or no free instance."""


def resolve_px4_dir(configured: str | None) -> Path:
    """The PX4 installation to run: ``UAVBAR_PX4_DIR``, else the configured one, else the
    cache (filled from the project's firmware archive, checked against its SHA-256)."""
    chosen = os.environ.get(PX4_DIR_ENV) or configured
    if chosen:
        path = Path(chosen).expanduser()
        _check_install(path)
        return path
    cached = CACHE_DIR / BUILD_NAME
    if not (cached / "bin" / "px4").exists():
        archive = next((a for a in ARCHIVE_CANDIDATES if a.exists()), None)
        if archive is None:
            raise FirmwareError(
                f"no PX4 SITL installation: set {PX4_DIR_ENV} or sim.px4_dir to an extracted "
                f"{BUILD_NAME} (holding bin/px4 and etc/), or put {BUILD_NAME}.tar.xz at "
                f"{ARCHIVE_CANDIDATES[0]}"
            )
        extract_archive(archive, CACHE_DIR)
    _check_install(cached)
    return cached


def _check_install(path: Path) -> None:
    if not (path / "bin" / "px4").exists() or not (path / "etc" / "init.d-posix").is_dir():
        raise FirmwareError(f"{path} is not a PX4 SITL installation (no bin/px4 and etc/)")


def extract_archive(archive: Path, destination: Path) -> Path:
    """Check ``archive`` against the pinned SHA-256 and extract it under ``destination``
    (atomically: into a temporary folder renamed at the end)."""
    digest = hashlib.sha256()
    with archive.open("rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    if digest.hexdigest() != ARCHIVE_SHA256:
        raise FirmwareError(f"{archive}: SHA-256 {digest.hexdigest()} is not the pinned build's")
    destination.mkdir(parents=True, exist_ok=True)
    staging = destination / f".{BUILD_NAME}.{os.getpid()}"
    with tarfile.open(archive) as tar:
        tar.extractall(staging, filter="tar")
    target = destination / BUILD_NAME
    with contextlib.suppress(OSError):
        (staging / BUILD_NAME).rename(target)  # another process may have won the race
    shutil.rmtree(staging, ignore_errors=True)
    log.info("PX4 SITL extracted to %s", target)
    return target


def _port_free(kind: int, port: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _instance_free(n: int) -> bool:
    lock = Path(f"/tmp/px4_lock-{n}")
    if lock.exists():
        try:
            with lock.open("rb") as handle:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                fcntl.flock(handle, fcntl.LOCK_UN)
        except OSError:
            return False
    return (
        _port_free(socket.SOCK_STREAM, SIMULATOR_PORT + n)
        and _port_free(socket.SOCK_DGRAM, OFFBOARD_LOCAL_PORT + n)
        and _port_free(socket.SOCK_DGRAM, OFFBOARD_REMOTE_PORT + n)
    )


def free_instances(count: int, first: int = 0) -> tuple[int, ...]:
    """``count`` consecutive PX4 instance numbers, from ``first`` on, whose lock file and
    ports nobody holds."""
    for start in range(first, MAX_INSTANCE - count + 2):
        if all(_instance_free(n) for n in range(start, start + count)):
            return tuple(range(start, start + count))
    raise FirmwareError(f"no {count} free PX4 instances in 0..{MAX_INSTANCE}")


# PX4's default rate P gains (MC_ROLLRATE_P, MC_PITCHRATE_P, MC_YAWRATE_P; parameters.json):
# normalized torque per rad/s of rate error.
DEFAULT_RATE_P = (0.15, 0.15, 0.2)


def rate_gain_multipliers(
    unit_torque_nm: tuple[float, float, float],
    inertia_kgm2: tuple[float, float, float],
    bandwidth_per_s: tuple[float, float, float],
) -> tuple[float, float, float]:
    """MC_ROLLRATE_K, MC_PITCHRATE_K, MC_YAWRATE_K that give PX4's rate loop the
    proportional ``bandwidth_per_s`` (angular acceleration per rate error) on this
    airframe: P·K·(torque per normalized unit)/J. PX4's defaults are tuned for a lighter
    frame with longer arms; the paper's UAV needs about twice the pitch gain."""
    values = [
        min(5.0, max(0.01, b * j / (p * t)))
        for b, j, p, t in zip(
            bandwidth_per_s, inertia_kgm2, DEFAULT_RATE_P, unit_torque_nm, strict=True
        )
    ]
    return round(values[0], 3), round(values[1], 3), round(values[2], 3)


@dataclass(frozen=True)
class LabParameters:
    """The PX4 parameters a mocap lab flies with, written before boot."""

    system_id: int
    offboard_loss_timeout_s: float
    hover_thrust: float  # MPC_THR_HOVER, normalized
    rate_gain_k: tuple[float, float, float] = (1.0, 1.0, 1.0)
    ulog: bool = False  # a ULog of each flight, from arm to disarm, in the working dir's log/

    def values(self) -> dict[str, float | int]:
        return {
            "MAV_SYS_ID": self.system_id,
            # No GPS; position, height and heading from the mocap. The barometer stays on
            # (PX4's default) as the height without vision: with the mocap its only height,
            # a PX4 whose vision stopped (its agent killed) ended in flight termination.
            "EKF2_GPS_CTRL": 0,
            "EKF2_EV_CTRL": 15,  # horizontal + vertical position, velocity, yaw
            "EKF2_HGT_REF": 3,  # vision
            "EKF2_BARO_CTRL": 1,
            "EKF2_MAG_TYPE": 5,  # none: the arena's yaw, not north
            "EKF2_EV_DELAY": 0.0,  # the supervisor stamps poses with their capture time
            "SYS_HAS_GPS": 0,
            # Offboard loss: land after the chosen timeout (default: hold in POSCTL).
            "COM_OBL_RC_ACT": 4,
            "COM_OF_LOSS_T": self.offboard_loss_timeout_s,
            "COM_RC_IN_MODE": 4,  # no RC and no joystick in a mocap arena
            "NAV_RCL_ACT": 0,
            "NAV_DLL_ACT": 0,
            "MPC_THR_HOVER": self.hover_thrust,
            "THR_MDL_FAC": 0.0,  # thrust linear in the motor output (sim/motor_mixer.py)
            "MC_ROLLRATE_K": self.rate_gain_k[0],
            "MC_PITCHRATE_K": self.rate_gain_k[1],
            "MC_YAWRATE_K": self.rate_gain_k[2],
            # Without a ULog: saves a core's worth of writes on long runs.
            "SDLOG_MODE": 0 if self.ulog else -1,
        }

    def script(self) -> str:
        """``px4-rc.params``: one ``param set`` per value."""
        lines = ["#!/bin/sh", "# written by uavbar-supervisor before boot"]
        lines += [f"param set {name} {value}" for name, value in self.values().items()]
        return "\n".join(lines) + "\n"


def _prepare_child() -> None:
    """In the child before exec: SIGTERM when the world process dies, however it dies; and
    PX4's threads kept below the supervisor. As root PX4 gives its threads SCHED_FIFO 40–99
    (measured), above the flight process and the world feeding its sensors; a real PX4 has
    its own processor. Without CAP_SYS_NICE its requests fail and PX4 (by design) creates
    the threads with the scheduling they inherit: ``PX4_PRIORITY`` where the machine allows
    real-time scheduling, else the world's own."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    with contextlib.suppress(OSError):
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PX4_PRIORITY))
    libc.prctl(PR_CAPBSET_DROP, CAP_SYS_NICE)
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))


class Px4Process:
    """One PX4 SITL instance in its own working directory."""

    def __init__(
        self, px4_dir: Path, instance: int, working_dir: Path, parameters: LabParameters
    ) -> None:
        self.px4_dir = px4_dir
        self.instance = instance
        self.working_dir = working_dir
        self.parameters = parameters
        self._process: asyncio.subprocess.Process | None = None

    @property
    def log_path(self) -> Path:
        return self.working_dir / "px4.log"

    async def start(self, extra_env: Mapping[str, str] | None = None) -> None:
        hooks = self.working_dir / "rc"
        hooks.mkdir(parents=True, exist_ok=True)
        (hooks / "px4-rc.params").write_text(self.parameters.script())
        env = {
            **os.environ,
            "PX4_SYS_AUTOSTART": AIRFRAME.split("_", 1)[0],
            "PX4_SIM_MODEL": AIRFRAME.split("_", 1)[1],
            "PATH": f"{hooks}:{self.px4_dir / 'bin'}:{os.environ.get('PATH', '')}",
            **(extra_env or {}),
        }
        env.pop("PX4_SIMULATOR", None)
        with self.log_path.open("wb") as output:
            self._process = await asyncio.create_subprocess_exec(
                str(self.px4_dir / "bin" / "px4"),
                "-d",
                "-i",
                str(self.instance),
                str(self.px4_dir / "etc"),
                cwd=self.working_dir,
                env=env,
                stdin=asyncio.subprocess.DEVNULL,
                stdout=output,
                stderr=asyncio.subprocess.STDOUT,
                preexec_fn=_prepare_child,
                start_new_session=True,
            )
        log.info("PX4 instance %d started (pid %d, %s)", self.instance, self.pid, self.working_dir)

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.returncode is None

    async def stop(self) -> None:
        """SIGTERM, then SIGKILL after ``STOP_TIMEOUT_S``."""
        process, self._process = self._process, None
        if process is None or process.returncode is not None:
            return
        with contextlib.suppress(ProcessLookupError):
            process.terminate()
        try:
            async with asyncio.timeout(STOP_TIMEOUT_S):
                await process.wait()
        except TimeoutError:
            with contextlib.suppress(ProcessLookupError):
                process.kill()
            await process.wait()
