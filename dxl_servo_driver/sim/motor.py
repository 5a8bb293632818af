"""
Geared DC motor and thermal model of the XM430-class servo, fitted to the seed's datasheet.

All mechanical figures are referred to the output horn (after the 353.5:1 gearbox). The motor is
a coreless DC motor whose inductance is neglected (electrical time constant far below the 1 ms
control period), so the winding current follows the applied voltage algebraically:

    i = (duty * V_in - K_e * w) / R
    J * dw/dt = K_t * i - B * w - sign(w) * (T_c + load)

Fit (minimax of the relative errors against the datasheet, see the test file for the check):

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

Thermal: one thermal mass to ambient, heated by the winding loss i^2 R plus the 40 mA standby
current of the electronics: 4 degC/W and a 300 s time constant (stall at 12 V heats by ~100 degC
towards equilibrium, a few minutes to trip 80 degC). The winding resistance is kept constant.
"""

import math

GEAR_RATIO = 353.5
PULSES_PER_REV = 4096
PULSE_PER_RAD = PULSES_PER_REV / (2.0 * math.pi)
RPM_PER_VELOCITY_UNIT = 0.229
AMPERE_PER_CURRENT_UNIT = 0.00269
PWM_FULL_RAW = 885            # 885 = 100 % duty
VOLT_PER_VOLTAGE_UNIT = 0.1

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


def stall_current_a(volts: float) -> float:
    """Steady current with the horn held still at full duty."""
    return volts / RESISTANCE_OHM


def stall_torque_nm(volts: float) -> float:
    """Torque delivered to a load holding the horn still at full duty."""
    return TORQUE_CONSTANT_NM_A * stall_current_a(volts) - COULOMB_FRICTION_NM


def no_load_speed_rad_s(volts: float) -> float:
    """Steady free-running speed at full duty (analytic steady state of the model)."""
    drive = volts - RESISTANCE_OHM * COULOMB_FRICTION_NM / TORQUE_CONSTANT_NM_A
    damping = BACK_EMF_V_S_RAD + RESISTANCE_OHM * VISCOUS_FRICTION_NM_S_RAD / TORQUE_CONSTANT_NM_A
    return max(0.0, drive / damping)


def rad_s_to_rpm(rad_s: float) -> float:
    """Convert rad/s to rpm."""
    return rad_s * 60.0 / (2.0 * math.pi)


def heat_power_w(current_sq_a2: float, volts: float) -> float:
    """Heat dissipated for a mean squared winding current: i^2 R plus the standby electronics."""
    return current_sq_a2 * RESISTANCE_OHM + STANDBY_CURRENT_A * volts


def thermal_step(temperature_c: float, ambient_c: float, power_w: float, dt_s: float) -> float:
    """Exact first-order response over dt_s at constant power (any dt_s, no sub-steps needed)."""
    equilibrium_c = ambient_c + THERMAL_RESISTANCE_C_W * power_w
    decay = math.exp(-dt_s / THERMAL_TIME_CONSTANT_S)
    return equilibrium_c + (temperature_c - equilibrium_c) * decay
