"""
`dxl adapters`: the USB serial adapters on this machine, which one is the bus's, its udev rule.

  dxl adapters                        list them: /dev/serial/by-id names, the device, the USB
                                      driver, the latency timer and what it costs
  dxl adapters --find                 unplug the bus's adapter, plug it back: names it
  dxl adapters --udev-rule PATH [--device DEV] [--name ttyDXL]
                                      write a udev rule for it: /dev/ttyDXL, latency timer 1 ms

Everything is read from Linux's device tree (/dev/serial/by-id, /sys/class/tty, the
usb-serial latency_timer of serial_port.SYSFS_LATENCY), as a function of a root path: the tests
build a tree that mirrors sysfs and point --root at it. An FTDI adapter (the U2D2) holds every
reply until its latency timer runs out (16 ms unless a udev rule sets it), so each transaction
may wait that long: the rule written here (the form of udev/99-dxl-servo-driver.rules) sets 1 ms.
"""

import argparse
from dataclasses import dataclass
import os
import sys
import time
from typing import Callable, Dict, List, Optional, Sequence

from dxl_servo_driver.tool.common import EXIT_FAILED, EXIT_OK, EXIT_OUTPUT, EXIT_USAGE, ToolError

BY_ID = 'dev/serial/by-id'
CLASS_TTY = 'sys/class/tty'
LATENCY = 'sys/bus/usb-serial/devices/{name}/latency_timer'
# Device names a USB serial adapter gets: usb-serial drivers (FTDI, CP210x, CH34x) and CDC ACM.
PREFIXES = ('ttyUSB', 'ttyACM')
# Linux's FTDI driver holds replies this long unless told otherwise.
FTDI_DEFAULT_MS = 16.0
POLL_S = 0.2
DEFAULT_FIND_TIMEOUT_S = 60.0
# udev makes the /dev/serial/by-id links a moment after the kernel made the device.
BY_ID_GRACE_S = 2.0


@dataclass(frozen=True)
class Adapter:
    """One USB serial adapter, as Linux describes it."""

    device: str                      # /dev/ttyUSB0
    by_id: Sequence[str]             # its /dev/serial/by-id paths
    driver: Optional[str]            # the kernel driver (ftdi_sio, cp210x, cdc_acm ...)
    latency_ms: Optional[float]      # the usb-serial latency timer, None where it has none
    vendor: Optional[str] = None     # USB idVendor, idProduct (hex), serial, product text
    product_id: Optional[str] = None
    serial: Optional[str] = None
    product: Optional[str] = None

    @property
    def name(self) -> str:
        """Return the kernel name of the device, e.g. ttyUSB0."""
        return os.path.basename(self.device)


def _read(path: str) -> Optional[str]:
    try:
        with open(path, encoding='ascii', errors='replace') as stream:
            return stream.read().strip()
    except OSError:
        return None


def _target(link: str) -> str:
    """Return where a symlink in the tree points, inside the same tree."""
    return os.path.normpath(os.path.join(os.path.dirname(link), os.readlink(link)))


def list_adapters(root: str = '/') -> List[Adapter]:
    """Return the USB serial adapters the tree under root describes, by device name."""
    by_id: Dict[str, List[str]] = {}
    by_id_dir = os.path.join(root, BY_ID)
    try:
        entries = sorted(os.listdir(by_id_dir))
    except OSError:
        entries = []
    for entry in entries:
        link = os.path.join(by_id_dir, entry)
        if os.path.islink(link):
            name = os.path.basename(_target(link))
            by_id.setdefault(name, []).append(os.path.join('/', BY_ID, entry))
    names = set(by_id)
    try:
        names |= {name for name in os.listdir(os.path.join(root, CLASS_TTY))
                  if name.startswith(PREFIXES)}
    except OSError:
        pass
    return [_describe(root, name, by_id.get(name, [])) for name in sorted(names, key=_order)]


def _order(name: str) -> tuple:
    stem = name.rstrip('0123456789')
    return (stem, int(name[len(stem):] or 0))


def _describe(root: str, name: str, by_id: Sequence[str]) -> Adapter:
    device_link = os.path.join(root, CLASS_TTY, name, 'device')
    driver: Optional[str] = None
    usb: Dict[str, Optional[str]] = {}
    if os.path.islink(device_link):
        device_dir = _target(device_link)
        driver_link = os.path.join(device_dir, 'driver')
        if os.path.islink(driver_link):
            driver = os.path.basename(_target(driver_link))
        # The USB device (idVendor ...) is the tty's parent or grandparent (interface, device).
        where = device_dir
        for _ in range(3):
            where = os.path.dirname(where)
            if os.path.exists(os.path.join(where, 'idVendor')):
                usb = {key: _read(os.path.join(where, key))
                       for key in ('idVendor', 'idProduct', 'serial', 'product')}
                break
    latency = _read(os.path.join(root, LATENCY.format(name=name)))
    try:
        latency_ms: Optional[float] = float(latency) if latency is not None else None
    except ValueError:
        latency_ms = None
    return Adapter(f'/dev/{name}', tuple(by_id), driver, latency_ms, usb.get('idVendor'),
                   usb.get('idProduct'), usb.get('serial'), usb.get('product'))


def latency_cost(latency_ms: Optional[float], driver: Optional[str]) -> str:
    """Return what the latency timer costs a bus, in words."""
    if latency_ms is None:
        if driver == 'ftdi_sio':
            return 'latency timer unknown (not readable)'
        return 'no latency timer in sysfs (replies are timed by the driver at configure)'
    text = (f'latency timer {latency_ms:g} ms: each reply may wait up to {latency_ms:g} ms '
            f'(at most ~{1000.0 / max(latency_ms, 0.125):.0f} transactions/s)')
    if latency_ms > 1.0:
        text += '; set 1 ms with `dxl adapters --udev-rule`'
    return text


def describe(adapter: Adapter) -> List[str]:
    """Return the lines `dxl adapters` prints for one adapter."""
    usb = ''
    if adapter.vendor:
        usb = f' USB {adapter.vendor}:{adapter.product_id}'
        if adapter.product:
            usb += f' "{adapter.product}"'
        if adapter.serial:
            usb += f' serial {adapter.serial}'
    lines = [f'{adapter.device}: driver {adapter.driver or "?"}{usb}']
    lines += [f'  {path} -> {adapter.device}' for path in adapter.by_id]
    lines.append(f'  {latency_cost(adapter.latency_ms, adapter.driver)}')
    return lines


def udev_rule(adapter: Adapter, symlink: str = 'ttyDXL') -> str:
    """Return a udev rule for this adapter (the form of udev/99-dxl-servo-driver.rules)."""
    if not adapter.vendor or not adapter.product_id:
        raise ToolError(f'{adapter.device}: Linux does not say its USB vendor and product ids: '
                        'no rule can match it')
    kernel = adapter.name.rstrip('0123456789') + '[0-9]*'
    match = (f'SUBSYSTEM=="tty", KERNEL=="{kernel}", ATTRS{{idVendor}}=="{adapter.vendor}", '
             f'ATTRS{{idProduct}}=="{adapter.product_id}"')
    if adapter.serial:
        match += f', ATTRS{{serial}}=="{adapter.serial}"'
    lines = [f'# udev rule for the Dynamixel bus on {adapter.device} (written by dxl adapters '
             '--udev-rule):',
             f'#   - names it /dev/{symlink}; lets every user open it; keeps ModemManager away;',
             '#   - sets the latency timer to 1 ms (FTDI), so no reply is held up to 16 ms.',
             '# Install: sudo cp THIS_FILE /etc/udev/rules.d/99-dxl-servo-driver.rules',
             '#          sudo udevadm control --reload && sudo udevadm trigger',
             f'{match}, SYMLINK+="{symlink}", MODE="0666", ENV{{ID_MM_DEVICE_IGNORE}}="1"']
    if adapter.driver == 'ftdi_sio' or adapter.latency_ms is not None:
        lines.append("# The tty's parent device (the usb-serial port) holds the latency_timer.")
        lines.append(f'{match}, ATTR{{device/latency_timer}}="1"')
    else:
        lines.append(f'# driver {adapter.driver or "?"} has no latency_timer attribute: nothing '
                     'to set.')
    return '\n'.join(lines) + '\n'


def register(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add `adapters`."""
    parser = sub.add_parser(
        'adapters', help="list the USB serial adapters; find the bus's; write its udev rule",
        description='List the USB serial adapters (by-id names, device, driver, latency timer '
        'and its cost); --find names the one you unplug and plug back; --udev-rule writes a '
        'rule naming it /dev/ttyDXL with a 1 ms latency timer.',
        epilog='examples:\n  dxl adapters\n  dxl adapters --find\n'
        '  dxl adapters --udev-rule 99-dxl.rules --device /dev/ttyUSB0',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--find', action='store_true',
                        help="ask to unplug then replug the bus's adapter, and name it")
    parser.add_argument('--udev-rule', metavar='PATH', help='write a udev rule for the adapter')
    parser.add_argument('--device', metavar='DEV',
                        help='the adapter for --udev-rule (default: the only one)')
    parser.add_argument('--name', default='ttyDXL', help='the symlink --udev-rule makes')
    parser.add_argument('--timeout', type=float, default=DEFAULT_FIND_TIMEOUT_S, metavar='S',
                        help=f'--find: how long to wait for each step (default '
                        f'{DEFAULT_FIND_TIMEOUT_S:g} s)')
    parser.add_argument('--root', default='/', help=argparse.SUPPRESS)   # tests: a fake tree
    parser.set_defaults(run=run)


def _wait_change(root: str, before: Sequence[str], gone: bool, timeout_s: float,
                 sleep: Callable[[float], None]) -> List[str]:
    """Wait until devices vanish (gone) or appear; return those names."""
    deadline = time.monotonic() + timeout_s
    while True:
        now = [adapter.name for adapter in list_adapters(root)]
        changed = ([name for name in before if name not in now] if gone
                   else [name for name in now if name not in before])
        if changed:
            return changed
        if time.monotonic() > deadline:
            return []
        sleep(POLL_S)


def find(root: str, timeout_s: float,
         sleep: Callable[[float], None] = time.sleep) -> Adapter:
    """
    Ask for the bus's adapter to be unplugged and plugged back; return it.

    sleep is called between two looks at the tree (a test steps the tree's changes with it).
    """
    before = [adapter.name for adapter in list_adapters(root)]
    if not before:
        raise ToolError('no USB serial adapter is plugged in')
    print(f'{len(before)} adapter(s): {", ".join(before)}. Unplug the servo bus\'s adapter '
          'now ...', flush=True)
    gone = _wait_change(root, before, True, timeout_s, sleep)
    if not gone:
        raise ToolError(f'no adapter was unplugged within {timeout_s:g} s')
    print(f'{", ".join(gone)} unplugged. Plug it back in ...', flush=True)
    remaining = [name for name in before if name not in gone]
    back = _wait_change(root, remaining, False, timeout_s, sleep)
    if not back:
        raise ToolError(f'no adapter came back within {timeout_s:g} s')
    if len(back) > 1:
        raise ToolError(f'{len(back)} adapters appeared ({", ".join(back)}): plug in one only')
    return _settled(root, back[0], timeout_s, sleep)


def _settled(root: str, name: str, timeout_s: float,
             sleep: Callable[[float], None]) -> Adapter:
    """
    Return the adapter that appeared as name once Linux has finished making it.

    A device appears in pieces (its sysfs entry, its driver bound, its /dev node, udev's by-id
    links last): described at its first sight it may have no driver yet. Waits until the
    driver is bound and the node is there (at most timeout_s), then for a by-id link a little
    longer where the adapter has a serial number to make one from.
    """
    deadline = time.monotonic() + timeout_s
    by_id_until: Optional[float] = None
    while True:
        adapter = next((each for each in list_adapters(root) if each.name == name), None)
        now = time.monotonic()
        if adapter is not None and adapter.driver is not None and os.path.exists(
                os.path.join(root, 'dev', name)):
            if adapter.by_id or adapter.serial is None:
                return adapter
            by_id_until = now + BY_ID_GRACE_S if by_id_until is None else by_id_until
            if now > by_id_until:
                return adapter
        elif now > deadline:
            if adapter is None:
                raise ToolError(f'{name} appeared and went again: plug it in once more')
            return adapter
        sleep(POLL_S)


def run(args: argparse.Namespace) -> int:
    """List, find, or write a rule."""
    if args.find:
        adapter = find(args.root, args.timeout)
        print("the bus's adapter is:")
        for line in describe(adapter):
            print(line)
    elif args.udev_rule:
        adapters = list_adapters(args.root)
        if args.device:
            wanted = os.path.basename(os.path.realpath(args.device)
                                      if args.root == '/' else args.device)
            chosen = [adapter for adapter in adapters
                      if adapter.name == wanted or args.device in adapter.by_id]
            if not chosen:
                raise ToolError(f'{args.device} is not a USB serial adapter here', EXIT_USAGE)
        elif len(adapters) != 1:
            raise ToolError(f'{len(adapters)} adapters: name one with --device '
                            f'({", ".join(a.device for a in adapters) or "none plugged in"})',
                            EXIT_USAGE)
        else:
            chosen = adapters
        adapter = chosen[0]
        text = udev_rule(adapter, args.name)
        try:
            with open(args.udev_rule, 'w', encoding='ascii') as stream:
                stream.write(text)
        except OSError as exc:
            raise ToolError(f'{args.udev_rule} cannot be written: {exc.strerror}',
                            EXIT_OUTPUT) from exc
        print(f'wrote {args.udev_rule} for {adapter.device}: /dev/{args.name}, latency timer '
              f'1 ms. Install it with:\n  sudo cp {args.udev_rule} /etc/udev/rules.d/'
              '99-dxl-servo-driver.rules\n  sudo udevadm control --reload && sudo udevadm '
              'trigger')
    else:
        adapters = list_adapters(args.root)
        if not adapters:
            print('no USB serial adapter found (nothing under /dev/serial/by-id or '
                  '/sys/class/tty/ttyUSB*, ttyACM*)', file=sys.stderr)
            return EXIT_FAILED
        for adapter in adapters:
            for line in describe(adapter):
                print(line)
    return EXIT_OK
