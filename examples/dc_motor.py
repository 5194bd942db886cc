"""An armature-controlled DC motor with an inertial load: a physics plug-in in state-space form.

    L di/dt = u − R i − K ω          (armature circuit: u in V, i in A)
    J dω/dt = K i − b ω              (shaft: ω in rad/s)

The output is the shaft speed ω (rad/s), as a tachometer reads it. R, K and b
are the datasheet's and the ohmmeter's, frozen by default; a fit moves the
inductance L and the inertia J. The drive is held between samples (a DAC or a
PWM amplifier), and each sample is integrated in `substeps` RK4 steps of the
state-space form, which also lets `hybrid diagnose` search effects inside
the dynamics (a limit on the speed, a restoring force fed back into the drive)
as well as on the drive and on the output. A force fed back from inside acts on
the shaft, as a torque (`forced_rates`): a Coulomb friction on the speed is then
read as a step in N m.

It came from a new user's trial of the library (a physics the repository did
not ship). `experiments/motor_wander.py` hides an additive wander of the
tachometer's zero in its data; `tests/test_plugins.py` checks it against
scipy's `solve_ivp`.
"""

from typing import ClassVar

from hybrid import AbstractStateSpace, Positive, encode


class DCMotor(AbstractStateSpace):
    raw: dict
    constraints: ClassVar[dict] = {
        "resistance": Positive(),
        "inductance": Positive(),
        "torque_constant": Positive(),
        "inertia": Positive(),
        "viscous": Positive(),
    }
    units: ClassVar[dict] = {
        "resistance": "ohm",
        "inductance": "H",
        "torque_constant": "N m/A",
        "inertia": "kg m^2",
        "viscous": "N m s/rad",
    }
    plausible: ClassVar[dict] = {
        "resistance": (0.01, 100.0),
        "inductance": (1e-4, 10.0),
        "torque_constant": (1e-3, 10.0),
        "inertia": (1e-6, 10.0),
        "viscous": (1e-5, 10.0),
    }
    typical: ClassVar[dict] = {"inertia": (1e-3, 0.1), "inductance": (0.01, 0.5)}
    frozen_by_default: ClassVar[dict] = {
        "resistance": "measured with an ohmmeter",
        "torque_constant": "the datasheet's; with the tachometer's fitted gain it only rescales the speed",
        "viscous": "the datasheet's",
    }
    states: ClassVar[tuple] = ("current", "speed")
    state_units: ClassVar[dict] = {"current": "A", "speed": "rad/s"}
    output_unit: ClassVar[str] = "rad/s"
    force_unit: ClassVar[str] = "N m"  # a force fed back from inside acts on the shaft (`forced_rates`)
    limited_states: ClassVar[tuple] = ("speed",)
    velocity_states: ClassVar[tuple] = ("speed",)  # a brush's or a bearing's dry friction acts on it
    substeps: ClassVar[int] = 4
    drive_between_samples: ClassVar[str] = "hold"
    linear_in_drive: ClassVar[bool] = True

    def __init__(self, resistance=2.0, inductance=0.1, torque_constant=0.1, inertia=0.02, viscous=0.02):
        values = dict(
            resistance=resistance,
            inductance=inductance,
            torque_constant=torque_constant,
            inertia=inertia,
            viscous=viscous,
        )
        self.raw = encode(values, self.constraints, "DCMotor")

    def rates(self, x, u, p):
        return self.forced_rates(x, u, 0.0, p)

    def forced_rates(self, x, u, force, p):
        """The rates with a torque `force` (N m) fed back onto the shaft, against the motor's own.

        A friction or a load acts on the shaft, not on the armature's voltage: taken off the drive (the
        default) it would pass through the armature's lag first, and a Coulomb friction's step would not
        read as one (`hybrid diagnose` reads the map it finds in `force_unit`).
        """
        i, w = x
        di = (u - p["resistance"] * i - p["torque_constant"] * w) / p["inductance"]
        dw = (p["torque_constant"] * i - p["viscous"] * w - force) / p["inertia"]
        return di, dw

    def drive_force(self, u, p):
        """The torque the drive exerts on a stalled shaft, K·u/R (N m): what a fed-back torque is sized against."""
        return p["torque_constant"] * u / p["resistance"]

    def observe(self, x, p):
        return x[1]
