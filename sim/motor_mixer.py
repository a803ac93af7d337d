"""Four rotors of a quad-X airframe as PX4's control allocation sees them: motor outputs
in [0, 1] → collective thrust and body torque. Pure; SI units.

The geometry is PX4's own: ``CA_ROTORn_PX/PY`` (rotor position, body FRD [m]) and
``CA_ROTORn_KM`` (yaw moment per newton of thrust, its sign the spin direction), read from
the airframe file PX4 mixes for (``none_iris``, the external-simulator quadrotor). With
``THR_MDL_FAC`` = 0 PX4's allocation takes a rotor's thrust as linear in its output,
``CA_ROTORn_CT`` × u, so that is the motor curve here: what PX4 believes is what flies.
PX4's effectiveness model (its ``ActuatorEffectivenessRotors``): a rotor pushing along
body −z at position r gives the moment CT·u·(r × −ẑ) + CT·u·KM·ẑ.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from geometry.arrays import FloatArray
from geometry.frames import flu_to_frd

# PX4's default rotor thrust coefficient (CA_ROTORn_CT, parameters.json): 6.5 N at u = 1.
DEFAULT_CT_N = 6.5
_PARAM_LINE = re.compile(r"param\s+set-default\s+CA_ROTOR(\d)_(PX|PY|KM|CT)\s+(-?[\d.]+)")


@dataclass(frozen=True)
class Rotor:
    """One rotor: position (FRD body) [m], yaw moment coefficient [m], thrust at u = 1 [N]."""

    px_m: float
    py_m: float
    km_m: float
    ct_n: float = DEFAULT_CT_N


@dataclass(frozen=True)
class QuadMixer:
    """The airframe's rotors and what their outputs produce."""

    rotors: tuple[Rotor, Rotor, Rotor, Rotor]

    @staticmethod
    def from_airframe(path: Path) -> QuadMixer:
        """The rotors of a PX4 airframe file (its ``param set-default CA_ROTORn_*`` lines)."""
        values: dict[tuple[int, str], float] = {}
        for match in _PARAM_LINE.finditer(path.read_text()):
            values[(int(match[1]), match[2])] = float(match[3])
        try:
            rotors = tuple(
                Rotor(
                    values[(n, "PX")],
                    values[(n, "PY")],
                    values[(n, "KM")],
                    values.get((n, "CT"), DEFAULT_CT_N),
                )
                for n in range(4)
            )
        except KeyError as missing:
            raise ValueError(f"{path}: no CA_ROTOR{missing.args[0][0]} geometry") from None
        return QuadMixer((rotors[0], rotors[1], rotors[2], rotors[3]))

    @property
    def thrust_max_n(self) -> float:
        """Collective thrust with every output at 1 [N]."""
        return sum(r.ct_n for r in self.rotors)

    def thrusts_n(self, outputs: FloatArray) -> FloatArray:
        """Each rotor's thrust [N] for outputs clipped to [0, 1]."""
        u = np.clip(np.asarray(outputs, dtype=float)[:4], 0.0, 1.0)
        result: FloatArray = u * np.array([r.ct_n for r in self.rotors])
        return result

    def wrench(self, outputs: FloatArray) -> tuple[float, FloatArray]:
        """(collective thrust [N], body torque FLU [N m]) of motor outputs in [0, 1]."""
        thrust = self.thrusts_n(outputs)
        torque_frd = np.zeros(3)
        for rotor, t in zip(self.rotors, thrust, strict=True):
            torque_frd += t * np.array([-rotor.py_m, rotor.px_m, rotor.km_m])
        return float(thrust.sum()), flu_to_frd(torque_frd)  # FRD ↔ FLU is its own inverse

    def torque_limits_nm(self) -> FloatArray:
        """The largest torque magnitude per axis the rotors can produce [N m]."""
        ct = np.array([r.ct_n for r in self.rotors])
        arms = np.array([[-r.py_m, r.px_m, r.km_m] for r in self.rotors])
        # Symmetric airframe: half the rotors push one way at full output, half are off.
        limits: FloatArray = np.abs(arms).T @ ct / 2.0
        return limits

    def unit_torque_nm(self) -> FloatArray:
        """The torque per axis (roll, pitch, yaw) of a unit normalized torque setpoint
        after PX4's allocation [N m]. PX4 allocates with the pseudo-inverse of the
        effectiveness matrix and scales its torque columns (``normalizeControlAllocation
        Matrix``): each column to an RMS of 1/√2 over the rotors acting on that axis, roll
        and pitch by the larger of their two scales, so a unit command gives 1/scale."""
        arms = np.array([[-r.py_m, r.px_m, r.km_m] for r in self.rotors])
        ct = np.array([r.ct_n for r in self.rotors])
        effectiveness = np.vstack([(arms * ct[:, None]).T, -ct])  # roll, pitch, yaw, thrust
        mix = np.linalg.pinv(effectiveness)
        scales = np.array(
            [
                math.sqrt(
                    float(mix[:, axis] @ mix[:, axis]) / (np.count_nonzero(arms[:, axis]) / 2.0)
                )
                for axis in range(3)
            ]
        )
        scales[:2] = scales[:2].max()
        result: FloatArray = 1.0 / scales
        return result
