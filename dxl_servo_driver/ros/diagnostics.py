"""
/diagnostics of one bus: the bus and its cycle, then one status per servo.

Built from what the manager and the cycle runner know; published by the node at 1 Hz from the
executor, so it still speaks when the cycle has stopped or stalled.
"""

from dataclasses import dataclass
from typing import Any, Dict, List, Mapping, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.driver.manager import (
    IDX_HW_ERROR, IDX_TEMPERATURE, IDX_TORQUE, IDX_VOLTAGE, Manager, Servo)

# A cycle that has not completed for this long (and five periods) is reported as stalled.
STALL_S = 1.0


@dataclass
class CycleFacts:
    """What the cycle runner measured."""

    measured_hz: float
    requested_hz: float
    stalled_s: float
    cycle_errors: int
    failure: Optional[BaseException]
    threads: int   # live cycle threads: 1 while active, 0 otherwise, never more


def _values(pairs: Mapping[str, Any]) -> List[KeyValue]:
    return [KeyValue(key=key, value=str(value)) for key, value in pairs.items()]


def diagnostics(node_name: str, config: DriverConfig, manager: Manager, facts: CycleFacts,
                lifecycle_state: str, thresholds: Mapping[str, float], stamp: Any,
                extra: Optional[Mapping[str, Any]] = None,
                grasping: Optional[Mapping[str, bool]] = None) -> DiagnosticArray:
    """Return the bus status (with extra values) and every servo's."""
    array = DiagnosticArray()
    array.header.stamp = stamp
    bus = _bus_status(node_name, config, manager, facts, lifecycle_state)
    if extra:
        bus.values.extend(_values(extra))
    array.status.append(bus)
    for servo in manager.order:
        status = _servo_status(node_name, config, servo, thresholds)
        if grasping is not None and servo.name in grasping:
            status.values.append(KeyValue(key='grasping', value=str(grasping[servo.name])))
        pair = manager.pairs.facts(servo.name)
        if pair:
            # A joint on two servos: how far apart they are, at the level that says it.
            level, text = pair
            status.values.append(KeyValue(key='secondary_apart', value=text))
            if level != 'ok' and status.level < _LEVELS[level]:
                status.level = _LEVELS[level]
                status.message = text
        array.status.append(status)
    return array


_LEVELS = {'warn': DiagnosticStatus.WARN, 'error': DiagnosticStatus.ERROR}


def _bus_status(node_name: str, config: DriverConfig, manager: Manager, facts: CycleFacts,
                state: str) -> DiagnosticStatus:
    bus = manager.bus
    budget = manager.bus_budget()
    measured = facts.measured_hz
    requested = facts.requested_hz
    status = DiagnosticStatus(name=f'{node_name}: bus {config.port}', hardware_id=config.port)
    status.level = DiagnosticStatus.OK
    status.message = f'{measured:.0f} Hz'
    if facts.failure is not None:
        status.level = DiagnosticStatus.ERROR
        status.message = f'the bus cycle stopped: {facts.failure!r}'
    elif state != 'active':
        status.level = DiagnosticStatus.WARN
        status.message = f'not active ({state})'
    elif manager.port_lost:
        status.level = DiagnosticStatus.ERROR
        status.message = f'port lost, reconnecting: {manager.port_error}'
    elif facts.stalled_s > max(STALL_S, 5.0 / requested):
        status.level = DiagnosticStatus.ERROR
        status.message = f'the bus cycle has not completed for {facts.stalled_s:.1f} s'
    elif measured < 0.9 * min(requested, budget.rate_limit_hz):
        status.level = DiagnosticStatus.WARN
        status.message = (f'{measured:.0f} Hz, below the requested {requested:g} Hz '
                          f'(bus limit {budget.rate_limit_hz:.0f} Hz)')
    counters = bus.counters if bus is not None else None
    stats = manager.stats
    status.values = _values({
        'port': config.port, 'baud_rate': config.baud_rate,
        'lifecycle_state': state,
        'loop_rate_requested_hz': f'{requested:g}',
        'loop_rate_measured_hz': f'{measured:.1f}',
        'bus_limit_hz': f'{budget.rate_limit_hz:.0f}',
        'read_mode': manager.read_mode_in_use,
        'goal_slots': manager.goal_slots_in_use,
        'cycles': stats.cycles, 'cycle_errors': facts.cycle_errors,
        'cycle_threads': facts.threads,
        'read_failures': stats.read_failures,
        'timeouts': counters.timeouts if counters else 0,
        'corrupt_replies': counters.corrupt if counters else 0,
        'status_errors': counters.status_errors if counters else 0,
        'discarded_replies': counters.stale if counters else 0,
        'stale_samples_refused': stats.stale_refused,
        'flushed_bytes': counters.flushed_bytes if counters else 0,
        'deadline_waits': counters.deadline_waits if counters else 0,
        # The slack every reply deadline has now: raised when replies came late (bus.py).
        'deadline_slack_ms': f'{bus.slack_s * 1e3:g}' if bus is not None else '',
        'adapter_echo': bus.echo if bus is not None else False,
        'retries': stats.retries, 'retry_successes': stats.retry_successes,
        'recoveries': stats.recoveries, 'port_lost': manager.port_lost,
    })
    return status


def _servo_status(node_name: str, config: DriverConfig, servo: Servo,
                  thresholds: Mapping[str, float]) -> DiagnosticStatus:
    status = DiagnosticStatus(name=f'{node_name}: {servo.name}',
                              hardware_id=f'{config.port} id {servo.servo_id}')
    state = servo.state
    problems: List[str] = []
    level = DiagnosticStatus.OK
    if not servo.online:
        level = DiagnosticStatus.ERROR
        problems.append('not on the bus')
    elif servo.status:
        level = DiagnosticStatus.WARN
        problems.append(servo.status)
    elif not servo.fresh:
        level = DiagnosticStatus.ERROR
        problems.append('not answering')
    values: Dict[str, Any] = {
        'id': servo.servo_id, 'model': servo.model.name, 'model_number': servo.model_number,
        'torque_constant_nm_per_a': f'{servo.units.torque_constant_nm_per_a:.4g}',
        'effort_from': servo.units.effort_register,
        'firmware_version': servo.firmware_version, 'operating_mode': servo.mode,
        'comm_errors': servo.comm_errors, 'stale_samples_refused': servo.stale_refused,
        'restarts': servo.restarts, 'recoveries': servo.recoveries,
        'turn_offset_pulses': servo.turn_offset, 'role': _role(servo)}
    if state is not None and servo.health_time:
        temperature = float(state[IDX_TEMPERATURE])
        voltage = servo.units.voltage_to_v(state[IDX_VOLTAGE])
        errors = servo.model.decode_hardware_errors(state[IDX_HW_ERROR])
        values.update({'temperature_c': temperature, 'input_voltage_v': f'{voltage:.1f}',
                       'torque_enabled': bool(state[IDX_TORQUE]),
                       'hardware_errors': ', '.join(errors) or 'none'})
        if errors:
            level = DiagnosticStatus.ERROR
            problems.append('hardware error: ' + ', '.join(errors))
        if temperature >= thresholds['temperature_error']:
            level = DiagnosticStatus.ERROR
            problems.append(f'temperature {temperature:.0f} C')
        elif temperature >= thresholds['temperature_warn']:
            level = max(level, DiagnosticStatus.WARN)
            problems.append(f'temperature {temperature:.0f} C')
        if not thresholds['voltage_low'] <= voltage <= thresholds['voltage_high']:
            level = max(level, DiagnosticStatus.WARN)
            problems.append(f'input voltage {voltage:.1f} V')
    status.level = level
    # A passive joint's torque off is what it is for: said, never a problem.
    said = [] if servo.joint.torque and not servo.joint.trigger else [_role(servo)]
    status.message = '; '.join(said + problems) or 'OK'
    status.values = _values(values)
    return status


def _role(servo: Servo) -> str:
    """Return what the joint is: driven, passive (never torqued), or a trigger (its spring)."""
    joint = servo.joint
    if not joint.torque:
        return 'passive (torque: false)'
    if joint.trigger:
        return (f'trigger (rest {joint.trigger_position:g}, spring '
                f'{joint.trigger_current:g} A)')
    return 'driven'
