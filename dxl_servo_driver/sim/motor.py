"""
Geared DC motor and thermal model of one servo, fitted to its model's datasheet.

All mechanical figures are referred to the output horn (after the gearbox). The motor is a DC
motor whose inductance is neglected (electrical time constant far below the 1 ms control
period), so the winding current follows the applied voltage algebraically:

    i = (duty * V_in - K_e * w) / R
    J * dw/dt = K_t * i - B * w - sign(w) * (T_c + load)

The XM430 manual's fit (MANUAL_MOTOR, its XM430-W350 datasheet: 353.5:1, minimax of the relative
errors against the manual's three voltage points, see test_sim_physics.py for the check):

* R from the stall currents V / I = 5.29, 5.22, 5.48 ohm -> R = 5.35 ohm
  (stall current errors -1.2 %, -2.5 %, +2.5 %).
* Stall torque = K_t * V / R - T_c with T_c = 0.02 N m -> K_t = 1.7905 N m/A at the horn
  (errors -2.8 %, -2.5 %, +2.8 %). The datasheet torque per volt falls with voltage, which
  no constant-parameter motor reproduces exactly; these are the best achievable.
* No-load speed w = (V - R T_c / K_t) / (K_e + R B / K_t) = 3.8736 rpm per volt above 0.06 V
  (errors -0.5 %, +0.5 %, -0.5 %). K_t = eta * K_e with a gearbox efficiency eta = 0.75 gives
  K_e = 2.3873 V s/rad and B = 0.02607 N m s/rad; the implied no-load current is 0.082 A at 12 V.
* Reflected inertia J = 0.015 kg m^2 (rotor ~1.2e-7 kg m^2 times 353.5^2): mechanical time
  constant J / (K_t K_e / R + B) = 18 ms, so a step reaches speed in tens of ms.

Models 1020 and 1030 use MANUAL_MOTOR unchanged: the manual is their authority, and its figures
are the XM430-W350 ones for both (models.MANUAL_DIFFERENCES). Every other model gets the manual's
motor scaled to its datasheet point at its nominal voltage (fit_motor), fitted exactly there:

* T_c scaled by stall torque (0.02 N m per 4.1 N m), J by the gear ratio squared (same rotor);
* R = V / I_stall, K_t = (T_stall + T_c) / I_stall;
* K_e and B from the no-load speed, keeping the manual's no-load current as the same share of the
  stall current (3.55 %). A fixed gear efficiency would not do: with eta = 0.75 the XH430-V210's
  back-EMF at its no-load speed would exceed its supply (negative viscous friction).

Only one datasheet point is fitted for those, so at other voltages the torque and speed scale
linearly with the supply, as in any constant-parameter motor.

Thermal (all models alike: the datasheets give nothing to fit): one thermal mass to ambient,
heated by the winding loss i^2 R plus the 40 mA standby current of the electronics: 4 degC/W
and a 300 s time constant (the manual's motor at 12 V stall heats by ~100 degC towards
equilibrium, a few minutes to trip 80 degC). The winding resistance is kept constant.
"""

from dataclasses import dataclass
import math

from dxl_servo_driver.models import Model, VoltagePoint
from dxl_servo_driver.sim.memory import MANUAL_MODEL, MANUAL_MODEL_NUMBERS

# The manual's datasheet (its model's physics): the gear ratio, and the point at the nominal
# 12 V (stall torque, stall current) that scales the fit to the other models.
GEAR_RATIO = MANUAL_MODEL.physics.gear_ratio
MANUAL_POINT = MANUAL_MODEL.physics.nominal

RESISTANCE_OHM = 5.35
TORQUE_CONSTANT_NM_A = 1.7905
GEAR_EFFICIENCY = 0.75
BACK_EMF_V_S_RAD = TORQUE_CONSTANT_NM_A / GEAR_EFFICIENCY
COULOMB_FRICTION_NM = 0.02
VISCOUS_FRICTION_NM_S_RAD = 0.02607
INERTIA_KG_M2 = 0.015

STANDBY_CURRENT_A = 0.040
THERMAL_RESISTANCE_C_W = 4.0
THERMAL_TIME_CONSTANT_S = 300.0


@dataclass(frozen=True)
class Motor:
    """One model's motor, gearbox and thermal constants, referred to the horn."""

    gear_ratio: float
    resistance_ohm: float
    torque_constant_nm_a: float
    back_emf_v_s_rad: float
    coulomb_friction_nm: float
    viscous_friction_nm_s_rad: float
    inertia_kg_m2: float
    standby_current_a: float = STANDBY_CURRENT_A
    thermal_resistance_c_w: float = THERMAL_RESISTANCE_C_W
    thermal_time_constant_s: float = THERMAL_TIME_CONSTANT_S

    def stall_current_a(self, volts: float) -> float:
        """Steady current with the horn held still at full duty."""
        return volts / self.resistance_ohm

    def stall_torque_nm(self, volts: float) -> float:
        """Torque delivered to a load holding the horn still at full duty."""
        return self.torque_constant_nm_a * self.stall_current_a(volts) - self.coulomb_friction_nm

    def no_load_speed_rad_s(self, volts: float) -> float:
        """Steady free-running speed at full duty (analytic steady state of the model)."""
        kt = self.torque_constant_nm_a
        r_ohm = self.resistance_ohm
        drive = volts - r_ohm * self.coulomb_friction_nm / kt
        damping = self.back_emf_v_s_rad + r_ohm * self.viscous_friction_nm_s_rad / kt
        return max(0.0, drive / damping)

    def heat_power_w(self, current_sq_a2: float, volts: float) -> float:
        """Heat dissipated for a mean squared winding current: i^2 R plus the electronics."""
        return current_sq_a2 * self.resistance_ohm + self.standby_current_a * volts

    def thermal_step(self, temperature_c: float, ambient_c: float, power_w: float,
                     dt_s: float) -> float:
        """Exact first-order response over dt_s at constant power (any dt_s, no sub-steps)."""
        equilibrium_c = ambient_c + self.thermal_resistance_c_w * power_w
        decay = math.exp(-dt_s / self.thermal_time_constant_s)
        return equilibrium_c + (temperature_c - equilibrium_c) * decay


MANUAL_MOTOR = Motor(GEAR_RATIO, RESISTANCE_OHM, TORQUE_CONSTANT_NM_A, BACK_EMF_V_S_RAD,
                     COULOMB_FRICTION_NM, VISCOUS_FRICTION_NM_S_RAD, INERTIA_KG_M2)


def rad_s_to_rpm(rad_s: float) -> float:
    """Convert rad/s to rpm."""
    return rad_s * 60.0 / (2.0 * math.pi)


MIN_MECHANICAL_TIME_S = 0.002


def rpm_to_rad_s(rpm: float) -> float:
    """Convert rpm to rad/s."""
    return rpm * 2.0 * math.pi / 60.0


def _manual_no_load_share() -> float:
    """Return the manual's no-load current at 12 V over its datasheet stall current."""
    volts = MANUAL_POINT.voltage_v
    current_a = (volts - BACK_EMF_V_S_RAD * MANUAL_MOTOR.no_load_speed_rad_s(volts)) \
        / RESISTANCE_OHM
    return current_a / MANUAL_POINT.stall_current_a


NO_LOAD_CURRENT_SHARE = _manual_no_load_share()


def fit_motor(gear_ratio: float, point: VoltagePoint) -> Motor:
    """Return the manual's motor scaled to match one datasheet point exactly (see above)."""
    volts = point.voltage_v
    stall_a = point.stall_current_a
    speed_rad_s = rpm_to_rad_s(point.no_load_speed_rpm)
    friction_nm = COULOMB_FRICTION_NM * point.stall_torque_nm / MANUAL_POINT.stall_torque_nm
    r_ohm = volts / stall_a
    kt = (point.stall_torque_nm + friction_nm) / stall_a
    no_load_a = NO_LOAD_CURRENT_SHARE * stall_a
    ke = (volts - r_ohm * no_load_a) / speed_rad_s
    viscous = (kt * no_load_a - friction_nm) / speed_rad_s
    inertia = INERTIA_KG_M2 * (gear_ratio / GEAR_RATIO) ** 2
    # A bare motor quicker than the 1 ms control period (the Y series: time constants of
    # 0.03..0.2 ms) cannot be simulated at that period: it turns the load inertia that gives
    # it MIN_MECHANICAL_TIME_S (it is always built into something). Every other model is slower.
    damping = kt * ke / r_ohm + viscous
    inertia = max(inertia, MIN_MECHANICAL_TIME_S * damping)
    return Motor(gear_ratio, r_ohm, kt, ke, friction_nm, viscous, inertia)


# Built once per model object: a bus of 50 servos of one model shares one Motor.
_MOTORS: dict[int, tuple[Model, Motor]] = {}


def motor_for(model: Model) -> Motor:
    """Return a model's motor: MANUAL_MOTOR for 1020/1030, else fit_motor at its nominal point."""
    cached = _MOTORS.get(id(model))
    if cached is not None and cached[0] is model:
        return cached[1]
    if model.number in MANUAL_MODEL_NUMBERS:
        fitted = MANUAL_MOTOR
    else:
        fitted = fit_motor(model.physics.gear_ratio, model.physics.nominal)
    _MOTORS[id(model)] = (model, fitted)
    return fitted
