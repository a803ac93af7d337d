"""A real PX4 (SITL) flying one UAV of the plant: the world's vehicle for
``sim.vehicles = "px4_sitl"``.

PX4 connects to our simulator port (TCP 4560+n) and is driven through PX4's simulator
MAVLink API (docs/reference/px4-offboard.md §5): we send HIL_SENSOR at ``sensor_rate_hz``
(IMU, magnetometer, barometer from the plant's true motion, ``sim.hil_sensors``); PX4
answers HIL_ACTUATOR_CONTROLS, whose motor outputs ``sim.motor_mixer`` turns into the
thrust and torque the plant's UAV receives. PX4's own offboard/API link (UDP 14580+n →
14540+n) is the supervisor's business: the world only reports its address.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time

import numpy as np

from geometry.arrays import FloatArray
from px4_mavlink.codec import MavlinkCodec
from sim.hil_sensors import ALL_FIELDS, HilSensors
from sim.motor_mixer import QuadMixer
from sim.ports import AirframePort
from sim.px4_firmware import (
    OFFBOARD_LOCAL_PORT,
    OFFBOARD_REMOTE_PORT,
    SIMULATOR_PORT,
    Px4Process,
)
from sim.sensor_schedule import SensorSchedule

log = logging.getLogger(__name__)

SIMULATOR_SYSTEM_ID = 1  # PX4 ignores HIL_SENSOR from system 0 (measured: no sensor data)
ARMED_FLAG = 128  # HIL_ACTUATOR_CONTROLS.mode: MAV_MODE_FLAG_SAFETY_ARMED


class Px4SitlVehicle:
    """``sim.world.SimulatedVehicle`` backed by one PX4 SITL process."""

    def __init__(
        self,
        airframe: AirframePort,
        process: Px4Process,
        mixer: QuadMixer,
        sensors: HilSensors,
        *,
        sensor_rate_hz: float = 250.0,
        host: str = "127.0.0.1",
    ) -> None:
        self.airframe = airframe
        self.process = process
        self.mixer = mixer
        self.sensors = sensors
        self.sensor_schedule = SensorSchedule.at_rate(sensor_rate_hz)
        self.host = host
        self.codec = MavlinkCodec(SIMULATOR_SYSTEM_ID, 51)
        self.outputs = np.zeros(4)
        self.armed = False
        self.sensor_messages = 0
        self.actuator_messages = 0
        self._server: asyncio.Server | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._sent_at_s: list[float] = []

    @property
    def instance(self) -> int:
        return self.process.instance

    @property
    def connected(self) -> bool:
        """PX4 is connected to its simulator port."""
        return self._writer is not None

    @property
    def link_address(self) -> tuple[str, int]:
        """PX4's end of its offboard/API link."""
        return self.host, OFFBOARD_LOCAL_PORT + self.instance

    @property
    def client_port(self) -> int:
        """The UDP port PX4 sends its offboard/API link to (the supervisor listens there)."""
        return OFFBOARD_REMOTE_PORT + self.instance

    def describe(self) -> str:
        host, port = self.link_address
        return f"{host}:{port}"

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._connected, self.host, SIMULATOR_PORT + self.instance
        )
        await self.process.start()

    async def close(self) -> None:
        await self.process.stop()
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None

    async def _connected(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if self._writer is not None:  # PX4 restarted: the newest connection is PX4
            self._writer.close()
        self._writer = writer
        log.info("PX4 instance %d connected to its simulator port", self.instance)
        try:
            while data := await reader.read(4096):
                self._received(data)
        finally:
            if self._writer is writer:
                self._writer = None
                self.outputs[:] = 0.0
                self.armed = False

    def _received(self, data: bytes) -> None:
        # A TCP stream: the parser keeps a frame split across reads.
        for message in self.codec.messages.parse_buffer(data) or []:
            if message.get_type() == "HIL_ACTUATOR_CONTROLS":
                self.actuator_messages += 1
                self.armed = bool(message.mode & ARMED_FLAG)
                self.outputs = np.asarray(message.controls[:4], dtype=float)

    def step(self, now_s: float) -> None:
        """Apply PX4's latest motor outputs; send the sensors when due."""
        thrust, torque = self.mixer.wrench(self.outputs) if self.armed else (0.0, np.zeros(3))
        self.airframe.command(thrust, torque)
        if self._writer is not None and self.sensor_schedule.take(now_s, time.monotonic()):
            self._send_sensors()

    def _send_sensors(self) -> None:
        sample = self.sensors.sample(self.airframe.state())
        a: FloatArray = sample.accel_frd_mps2
        g: FloatArray = sample.gyro_frd_radps
        m: FloatArray = sample.mag_frd_gauss
        self.codec.messages.hil_sensor_send(
            int(time.monotonic() * 1e6),
            float(a[0]), float(a[1]), float(a[2]),
            float(g[0]), float(g[1]), float(g[2]),
            float(m[0]), float(m[1]), float(m[2]),
            sample.abs_pressure_hpa, 0.0, sample.pressure_alt_m, sample.temperature_degc,
            ALL_FIELDS, 0,
        )  # fmt: skip
        self.sensor_messages += 1
        self._report_punctuality(time.monotonic())
        writer = self._writer
        if writer is not None:
            for frame in self.codec.outgoing():
                writer.write(frame)

    def _report_punctuality(self, now_s: float) -> None:
        """Every 10 s, how regularly the sensors went out (PX4 flies on them: a late sample
        is a late rate loop)."""
        sent = self._sent_at_s
        sent.append(now_s)
        if now_s - sent[0] < 10.0:
            return
        gaps_ms = np.diff(sent) * 1000.0
        log.info(
            "PX4 %d sensors: %.0f Hz, gap p50 %.1f ms, p99 %.1f ms, max %.1f ms",
            self.instance,
            len(gaps_ms) / (sent[-1] - sent[0]),
            np.percentile(gaps_ms, 50),
            np.percentile(gaps_ms, 99),
            gaps_ms.max(),
        )
        self._sent_at_s = [now_s]
