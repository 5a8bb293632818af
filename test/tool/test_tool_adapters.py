"""`dxl adapters`: listing, --find and --udev-rule, on a temporary tree that mirrors sysfs."""

import os
import pathlib
import shutil
from typing import Iterator, List, Optional

from dxl_cli import dxl, dxl_executable, TIMEOUT_S
from dxl_servo_driver.tool import adapters
import pexpect
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
U2D2_BY_ID = 'usb-FTDI_USB__-__Serial_Converter_FT6Z5XYZ-if00-port0'
USB = 'sys/devices/pci0000:00/0000:00:14.0/usb1'


def plug(root: pathlib.Path, name: str, port: str, vendor: str, product: str,
         driver: str, serial: str, latency_ms: Optional[int], by_id: str = '') -> None:
    """Make the tree show one USB serial adapter as Linux does (sysfs, /dev, by-id)."""
    for _ in plug_steps(root, name, port, vendor, product, driver, serial, latency_ms, by_id):
        pass


def plug_steps(root: pathlib.Path, name: str, port: str, vendor: str, product: str,
               driver: str, serial: str, latency_ms: Optional[int],
               by_id: str = '') -> Iterator[None]:
    """Make the adapter in the order Linux does, pausing (yield) after each change."""
    usb_device = root / USB / port
    interface = usb_device / f'{port}:1.0'
    tty_device = interface / name if name.startswith('ttyUSB') else interface
    tty_device.mkdir(parents=True, exist_ok=True)
    for key, value in (('idVendor', vendor), ('idProduct', product), ('serial', serial),
                       ('product', 'USB <-> Serial Converter')):
        (usb_device / key).write_text(value + '\n')
    yield
    tty_class = root / 'sys/class/tty' / name
    tty_class.mkdir(parents=True)
    yield
    os.symlink(os.path.relpath(tty_device, tty_class), tty_class / 'device')
    yield
    drivers = root / 'sys/bus/usb-serial/drivers' / driver
    drivers.mkdir(parents=True, exist_ok=True)
    os.symlink(os.path.relpath(drivers, tty_device), tty_device / 'driver')
    yield
    if latency_ms is not None:
        serial_dir = root / 'sys/bus/usb-serial/devices' / name
        serial_dir.mkdir(parents=True)
        (serial_dir / 'latency_timer').write_text(f'{latency_ms}\n')
        yield
    (root / 'dev').mkdir(exist_ok=True)
    (root / 'dev' / name).write_text('')
    yield
    if by_id:
        link_dir = root / 'dev/serial/by-id'
        link_dir.mkdir(parents=True, exist_ok=True)
        os.symlink(f'../../{name}', link_dir / by_id)


def unplug(root: pathlib.Path, name: str) -> None:
    """Remove an adapter from the tree as Linux does when it is unplugged."""
    for link in (root / 'dev/serial/by-id').glob('*'):
        if os.readlink(link).endswith('/' + name):
            link.unlink()
    shutil.rmtree(root / 'sys/class/tty' / name)
    shutil.rmtree(root / 'sys/bus/usb-serial/devices' / name, ignore_errors=True)
    (root / 'dev' / name).unlink()


@pytest.fixture
def tree(tmp_path: pathlib.Path) -> pathlib.Path:
    """Return a tree with a U2D2 (FTDI, 16 ms) on ttyUSB0 and a CDC ACM board on ttyACM0."""
    plug(tmp_path, 'ttyUSB0', '1-1', '0403', '6014', 'ftdi_sio', 'FT6Z5XYZ', 16, U2D2_BY_ID)
    plug(tmp_path, 'ttyACM0', '1-2', '2341', '0043', 'cdc_acm', '7543', None,
         'usb-Arduino_Uno_7543-if00')
    return tmp_path


def test_list_reads_by_id_driver_and_latency(tree: pathlib.Path) -> None:
    found = adapters.list_adapters(str(tree))
    assert [adapter.device for adapter in found] == ['/dev/ttyACM0', '/dev/ttyUSB0']
    acm, u2d2 = found
    assert u2d2.by_id == (f'/dev/serial/by-id/{U2D2_BY_ID}',)
    assert (u2d2.driver, u2d2.latency_ms, u2d2.vendor, u2d2.product_id, u2d2.serial) == (
        'ftdi_sio', 16.0, '0403', '6014', 'FT6Z5XYZ')
    assert (acm.driver, acm.latency_ms, acm.vendor) == ('cdc_acm', None, '2341')


def test_an_empty_tree_lists_nothing(tmp_path: pathlib.Path) -> None:
    assert adapters.list_adapters(str(tmp_path)) == []
    done = dxl('adapters', '--root', str(tmp_path))
    assert done.returncode == 1 and 'no USB serial adapter found' in done.stderr


def test_the_command_says_what_the_latency_costs(tree: pathlib.Path) -> None:
    done = dxl('adapters', '--root', str(tree))
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    at = lines.index('/dev/ttyUSB0: driver ftdi_sio USB 0403:6014 "USB <-> Serial Converter" '
                     'serial FT6Z5XYZ')
    assert lines[at + 1] == f'  /dev/serial/by-id/{U2D2_BY_ID} -> /dev/ttyUSB0'
    assert lines[at + 2].startswith('  latency timer 16 ms: each reply may wait up to 16 ms '
                                    '(at most ~62 transactions/s)')
    assert '--udev-rule' in lines[at + 2]
    assert any('cdc_acm' in line for line in lines)
    assert any('no latency timer in sysfs' in line for line in lines)


def test_a_1ms_timer_is_not_flagged() -> None:
    text = adapters.latency_cost(1.0, 'ftdi_sio')
    assert text.startswith('latency timer 1 ms') and '--udev-rule' not in text


def test_udev_rule_has_the_repository_rule_form(tree: pathlib.Path,
                                                tmp_path: pathlib.Path) -> None:
    rule = tmp_path / 'out.rules'
    done = dxl('adapters', '--root', str(tree), '--udev-rule', str(rule), '--device',
               '/dev/ttyUSB0')
    assert done.returncode == 0, done.stderr
    assert 'sudo cp' in done.stdout
    lines = [line for line in rule.read_text().splitlines() if not line.startswith('#')]
    match = ('SUBSYSTEM=="tty", KERNEL=="ttyUSB[0-9]*", ATTRS{idVendor}=="0403", '
             'ATTRS{idProduct}=="6014", ATTRS{serial}=="FT6Z5XYZ"')
    assert lines == [f'{match}, SYMLINK+="ttyDXL", MODE="0666", ENV{{ID_MM_DEVICE_IGNORE}}="1"',
                     f'{match}, ATTR{{device/latency_timer}}="1"']
    # The repository's rule sets the same attributes the same way.
    shipped = (ROOT / 'udev' / '99-dxl-servo-driver.rules').read_text()
    for part in ('SYMLINK+="ttyDXL"', 'MODE="0666"', 'ENV{ID_MM_DEVICE_IGNORE}="1"',
                 'ATTR{device/latency_timer}="1"'):
        assert part in shipped


def test_udev_rule_needs_one_adapter_named(tree: pathlib.Path, tmp_path: pathlib.Path) -> None:
    rule = tmp_path / 'out.rules'
    done = dxl('adapters', '--root', str(tree), '--udev-rule', str(rule))
    assert done.returncode == 2 and 'name one with --device' in done.stderr
    assert not rule.exists()
    done = dxl('adapters', '--root', str(tree), '--udev-rule', str(rule), '--device',
               '/dev/ttyUSB7')
    assert done.returncode == 2 and 'not a USB serial adapter here' in done.stderr
    # A CDC ACM adapter has no latency timer: the rule only names it.
    done = dxl('adapters', '--root', str(tree), '--udev-rule', str(rule), '--device',
               '/dev/ttyACM0', '--name', 'ttyARM')
    assert done.returncode == 0, done.stderr
    text = rule.read_text()
    assert 'SYMLINK+="ttyARM"' in text and 'latency_timer}="1"' not in text


def test_find_names_the_adapter_unplugged_and_plugged_back(tree: pathlib.Path) -> None:
    child = pexpect.spawn(dxl_executable(), ['adapters', '--find', '--root', str(tree),
                                             '--timeout', '30'],
                          encoding='utf-8', timeout=TIMEOUT_S)
    try:
        child.expect("Unplug the servo bus's adapter now")
        unplug(tree, 'ttyUSB0')
        child.expect('ttyUSB0 unplugged. Plug it back in')
        # It comes back under another number, as a replugged adapter may.
        plug(tree, 'ttyUSB1', '1-1', '0403', '6014', 'ftdi_sio', 'FT6Z5XYZ', 16, U2D2_BY_ID)
        child.expect("the bus's adapter is:\r\n/dev/ttyUSB1: driver ftdi_sio")
        child.expect(pexpect.EOF)
    finally:
        child.close()
    assert child.exitstatus == 0


def test_find_waits_for_an_adapter_that_appears_in_pieces(tree: pathlib.Path) -> None:
    # Linux makes a replugged adapter in steps (sysfs entry, driver, /dev node, by-id link
    # last); each look at the tree here sees one more step, so the first sight of the new name
    # is an entry with no driver yet. The name, driver and by-id link must all be reported.
    def changes() -> Iterator[None]:
        unplug(tree, 'ttyUSB0')
        yield
        yield from plug_steps(tree, 'ttyUSB1', '1-1', '0403', '6014', 'ftdi_sio', 'FT6Z5XYZ',
                              16, U2D2_BY_ID)

    steps = changes()
    looks: List[float] = []

    def next_step(poll_s: float) -> None:
        looks.append(poll_s)
        next(steps, None)

    found = adapters.find(str(tree), 30.0, sleep=next_step)
    assert (found.device, found.driver, found.latency_ms) == ('/dev/ttyUSB1', 'ftdi_sio', 16.0)
    assert found.by_id == (f'/dev/serial/by-id/{U2D2_BY_ID}',)
    assert len(looks) >= 8   # it did look while the adapter was half made


def test_find_gives_up_after_its_timeout(tree: pathlib.Path) -> None:
    done = dxl('adapters', '--find', '--root', str(tree), '--timeout', '0.5')
    assert done.returncode == 1
    assert done.stderr.strip() == ('dxl adapters: error: no adapter was unplugged within '
                                   '0.5 s')
