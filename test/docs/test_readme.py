"""
README.md and docs/ stay true to the code: tables, interface names, parameter files, links.

README.md is the first screen (what it is, `make run`, `make test`, the path from a simulated
servo to MoveIt); the reference is in docs/, one page per topic. The parameter tables are in
docs/parameters.md, the servo table in docs/servos.md.
"""

import pathlib
import re
import sys
import tempfile
from typing import Any, Dict, Iterator, List, Tuple

from dxl_servo_driver.config import check_parameter_file, validate
from dxl_servo_driver.models import SUPPORTED
import pytest
import yaml

ROOT = pathlib.Path(__file__).resolve().parents[2]
DOCS = ROOT / 'docs'
README = (ROOT / 'README.md').read_text()
# README.md and every page of docs/, by path.
PAGES: Dict[pathlib.Path, str] = {
    path: path.read_text() for path in [ROOT / 'README.md', *sorted(DOCS.glob('*.md'))]}
ALL_TEXT = '\n'.join(PAGES.values())
README_MAX_LINES = 120   # a first screen, not a manual: the reference is in docs/
LINK = re.compile(r'\[[^\]]*\]\(([^)\s]+)\)')


def prose_and_code(text: str) -> Tuple[List[str], List[str]]:
    """Return a page's text outside code blocks and its code blocks (each with its tag line)."""
    parts = text.split('```')
    assert len(parts) % 2 == 1, 'a code block is not closed'
    return parts[0::2], parts[1::2]


def headings(text: str) -> List[str]:
    """Return the GitHub anchors of a page's headings."""
    anchors = []
    for prose in prose_and_code(text)[0]:
        for line in prose.splitlines():
            match = re.match(r'#{1,6} (.+)', line)
            if match:
                title = re.sub(r'[^\w\- ]', '', match.group(1).strip().lower())
                anchors.append(title.replace(' ', '-'))
    return anchors


def test_parameter_table_matches_the_code() -> None:
    sys.path.insert(0, str(ROOT / 'tools'))
    try:
        from param_table import PAGE, rows
    finally:
        sys.path.pop(0)
    missing = [row for row in rows() if row not in (ROOT / PAGE).read_text()]
    assert not missing, (f'{PAGE} parameter table is out of date (python tools/param_table.py):\n'
                         + '\n'.join(missing))


def test_supported_servo_table_matches_the_models() -> None:
    page = (DOCS / 'servos.md').read_text()
    sys.path.insert(0, str(ROOT / 'tools'))
    try:
        from model_table import rows
    finally:
        sys.path.pop(0)
    missing = [row for row in rows() if row not in page]
    assert not missing, ('docs/servos.md servo table is out of date '
                         '(python tools/model_table.py):\n' + '\n'.join(missing))


def test_the_simulators_command_table_is_the_consoles() -> None:
    from dxl_servo_driver.sim.control import commands_markdown
    assert commands_markdown().rstrip('\n') in (DOCS / 'simulator.md').read_text(), (
        'docs/simulator.md: the console command table is out of date (paste '
        'dxl_servo_driver.sim.control.commands_markdown())')


def test_readme_shows_every_topic_service_and_executable() -> None:
    for name in ('make run', 'make test'):   # the first screen's two commands
        assert name in README, name
    for name in ('make run', 'make test', 'make bench', 'commands/position', 'commands/velocity',
                 'commands/current', 'commands/pwm', 'set_position', 'set_velocity', 'set_current',
                 'set_pwm', 'set_operating_mode', 'set_torque', 'reboot', 'read_register',
                 'write_register', 'servo_states', '/diagnostics', 'ros2 topic echo /joint_states',
                 'colcon build --base-paths', 'scan --port', 'virtual_bus --ids',
                 '99-dxl-servo-driver.rules', 'dxl_servo_driver.launch.py',
                 'follow_joint_trajectory', 'gripper_cmd', 'joint_trajectory', 'joint_command'):
        assert name in ALL_TEXT, f'{name} is in neither README.md nor docs/'


def test_readme_is_a_first_screen_that_leads_to_every_page() -> None:
    lines = README.count('\n')
    assert lines <= README_MAX_LINES, (
        f'README.md has {lines} lines: it is the first screen; put the reference in docs/')
    linked = {pathlib.Path(target.split('#')[0]) for target in LINK.findall(README)}
    for path in PAGES:
        if path.parent == DOCS:
            assert path.relative_to(ROOT) in linked, f'README.md does not link to {path.name}'


def test_the_scope_is_what_the_models_say() -> None:
    # Every model number the catalogue supports, on both protocols.
    count = len(SUPPORTED)
    assert f'{count} models of every family' in README, f'README.md: {count} models'
    assert 'Protocol 1.0 and 2.0' in README
    assert f'{count} model numbers of every DYNAMIXEL family' in (DOCS / 'servos.md').read_text()
    assert {model.protocol for variants in SUPPORTED.values() for model in variants} == {1.0, 2.0}


def links() -> Iterator[Tuple[pathlib.Path, str]]:
    """Yield every relative link of README.md and docs/: its page and its target."""
    for path, text in PAGES.items():
        for prose in prose_and_code(text)[0]:
            for target in LINK.findall(prose):
                if not re.match(r'[a-z]+:', target):
                    yield path, target


def test_every_link_lands_on_a_file_and_heading() -> None:
    checked = 0
    for page, target in links():
        name, _, anchor = target.partition('#')
        path = (page.parent / name).resolve() if name else page
        where = f'{page.relative_to(ROOT)}: ({target})'
        assert path.exists(), f'{where}: no file {name}'
        if anchor:
            assert path.suffix == '.md', where
            assert anchor in headings(path.read_text()), f'{where}: no heading #{anchor}'
        checked += 1
    assert checked >= 30


def flat(tree: Dict[str, Any], prefix: str = '') -> Dict[str, Any]:
    """Return ros__parameters flattened as ROS flattens them (`arm.registers.profile_velocity`)."""
    out: Dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(flat(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


def parameter_files() -> List[Tuple[str, str]]:
    """Return every whole parameter file shown (a YAML block from `/**:`): page and text."""
    files = []
    for path, text in PAGES.items():
        for block in prose_and_code(text)[1]:
            tag, _, body = block.partition('\n')
            if tag.strip() == 'yaml' and body.startswith('/**:'):
                files.append((str(path.relative_to(ROOT)), body))
    return files


@pytest.mark.parametrize('index', range(len(parameter_files())))
def test_each_parameter_file_shown_is_one_the_node_takes(index: int) -> None:
    page, text = parameter_files()[index]
    with tempfile.NamedTemporaryFile('w', suffix='.yaml') as stream:
        stream.write(text)
        stream.flush()
        check_parameter_file(stream.name)
    validate(flat(yaml.safe_load(text)['/**']['ros__parameters']))


def test_the_readme_joint_is_the_file_it_names() -> None:
    # The README's parameter file is config/one_joint.yaml, which `make run PARAMS=...` runs.
    assert 'make run PARAMS=config/one_joint.yaml' in README
    assert '```yaml\n' + (ROOT / 'config' / 'one_joint.yaml').read_text() + '```' in README
    assert len(parameter_files()) >= 2
