"""
The motor and gearbox of one simulated servo over one advance() span, at its supply and load.

ServoDynamics builds a Plant at the start of a span (dynamics.py) and its loop integrates the
horn with the Plant's constants; the current loops of the controllers (control_modes.py) invert
the same model to find the output that drives a current.
"""

import math

from dxl_servo_driver.sim import motor

# The servos' control period: controllers sample, and the motor is integrated, once per period.
CONTROL_PERIOD_S = 0.001


class Plant:
    """
    The motor and gearbox over one advance() span: its constants at this supply and load.

    The loop integrates the horn implicitly in the linear terms (stable at 1 ms whatever the
    motor), with stiction at rest; the current loops predict the speed from the same terms.
    """

    __slots__ = ('r_ohm', 'kt', 'ke', 'viscous', 'c1', 'ktr', 'denominator', 'friction', 'volts',
                 'volts_eff', 'low', 'high')

    def __init__(self, fitted: motor.Motor, load_nm: float, torque_on: bool,
                 volts: float, low: float = -math.inf, high: float = math.inf) -> None:
        self.r_ohm = fitted.resistance_ohm
        self.kt = fitted.torque_constant_nm_a
        self.ke = fitted.back_emf_v_s_rad
        self.viscous = fitted.viscous_friction_nm_s_rad
        self.c1 = CONTROL_PERIOD_S / fitted.inertia_kg_m2
        self.ktr = self.kt / self.r_ohm
        # The back-EMF brakes only through a driven winding: torque off is free-run.
        damping = (self.kt * self.ke / self.r_ohm + self.viscous) if torque_on else self.viscous
        self.denominator = 1.0 + self.c1 * damping
        self.friction = fitted.coulomb_friction_nm + load_nm
        self.volts = volts
        self.volts_eff = volts if volts > 1e-6 else 1e-6
        self.low = low     # the end stops, in horn pulses (+-inf: none)
        self.high = high

    def predict_omega(self, omega: float, current_a: float, pos: float) -> float:
        """
        Speed at the end of the period if current_a flows (current loop's back-EMF estimate).

        A real current loop runs far faster than the 1 ms period; anticipating the speed change
        keeps the held current exact while the horn accelerates, and at an end stop it knows
        the horn pushed into it stays put.
        """
        predicted = self._predict_free(omega, current_a)
        if (predicted > 0.0 and pos >= self.high) or (predicted < 0.0 and pos <= self.low):
            return 0.0
        return predicted

    def _predict_free(self, omega: float, current_a: float) -> float:
        """Speed at the end of the period if current_a flows and nothing stops the horn."""
        friction_nm = self.friction
        torque = self.kt * current_a - self.viscous * omega
        if omega > 0.0:
            torque -= friction_nm
        elif omega < 0.0:
            torque += friction_nm
        elif abs(torque) <= friction_nm:
            return 0.0
        else:
            torque -= math.copysign(friction_nm, torque)
        return omega + self.c1 * torque

    def duty_for(self, current_a: float, omega: float, full: float, pos: float) -> float:
        """Return the output (PWM raw units) that drives current_a at the predicted speed."""
        return (self.r_ohm * current_a + self.ke * self.predict_omega(omega, current_a, pos)) \
            / self.volts_eff * full
