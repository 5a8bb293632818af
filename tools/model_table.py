"""Print the table of supported servos of docs/servos.md from dxl_servo_driver/models."""

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from dxl_servo_driver.models import ALL_MODELS, SUPPORTED  # noqa: E402 - after the path set-up
from dxl_servo_driver.models.units import units_for  # noqa: E402

MODE_SHORT = {'current': 'cur', 'velocity': 'vel', 'position': 'pos',
              'extended_position': 'ext', 'current_based_position': 'cbp', 'pwm': 'pwm'}


def rows() -> list:
    """Return the table's lines: one per model (and firmware range where the table differs)."""
    lines = ['| model | number | protocol | modes | effort from | current unit | max baud | '
             'stall torque, no-load speed (nominal V) | notes |',
             '|---|---|---|---|---|---|---|---|---|']
    for model in ALL_MODELS:
        units = units_for(model)
        name = model.name
        variants = SUPPORTED[model.number]
        if model.min_firmware:
            name += f' (firmware {model.min_firmware}+)'
        elif len(variants) > 1:
            name += f' (firmware < {variants[1].min_firmware})'
        notes = []
        if not model.has('led'):
            notes.append('no LED')
        if model.has('external_port_mode_1'):
            notes.append('external ports 1-3')
        if not model.indirect:
            notes.append('no indirect entries: state read in place')
        elif len(model.indirect) < 22:
            notes.append(f'{len(model.indirect)} indirect entries: no PWM in servo_states')
        if not model.has('present_pwm'):
            notes.append('no PWM register')
        if not model.has('realtime_tick'):
            notes.append('no Realtime Tick')
        if model.protocol == 2.0 and model.fast_sync_read_firmware is None:
            notes.append('no Fast Sync Read')
        if not model.bulk_read:
            notes.append('no Bulk Read')
        if not model.reboot:
            notes.append('no REBOOT')
        modes = ', '.join(MODE_SHORT[mode] for mode in model.modes)
        effort = ('current' if units.effort_register == 'present_current'
                  else 'Present Load')
        unit = f'{model.current_unit_a * 1000:g} mA' if model.current_unit_a else '—'
        baud = max(model.bauds.values()) / 1e6
        point = model.physics.nominal
        lines.append(f'| {name} | {model.number} | {model.protocol:.1f} | {modes} | {effort} | '
                     f'{unit} | '
                     f'{baud:g} Mbps | {point.stall_torque_nm:g} N·m, '
                     f'{point.no_load_speed_rpm:g} rpm ({point.voltage_v:g} V) | '
                     f'{"; ".join(notes)} |')
    return lines


if __name__ == '__main__':
    print('\n'.join(rows()))
