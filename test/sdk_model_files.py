"""
Test helper: the model files of dynamixel-sdk (dynamixel_easy_sdk/control_table), read.

The independent source of every Protocol 2.0 table's addresses and sizes: test_models.py holds
the X series to it, test_model_families.py the other families. SDK is None (and needs_sdk skips)
when the package is missing.
"""

import importlib.util
import pathlib
import re

import pytest


def _sdk_tables() -> pathlib.Path | None:
    spec = importlib.util.find_spec('dynamixel_easy_sdk')
    if spec is None or not spec.submodule_search_locations:
        return None
    return pathlib.Path(list(spec.submodule_search_locations)[0]) / 'control_table'


SDK = _sdk_tables()
needs_sdk = pytest.mark.skipif(
    SDK is None, reason='dynamixel_easy_sdk (dynamixel-sdk 4.1) is not installed')

# SDK names that do not snake-case into ours (the X convention; the Y keeps its own names).
SDK_NAMES = {'Protocol Type': 'protocol_version', 'Secondary(Shadow) ID': 'secondary_id'}
# Rows of the model files that alias an indirect entry instead of naming an item.
SDK_ALIASES = {
    'Indirect Address Write': 'indirect_address_', 'Indirect Address Read': 'indirect_address_',
    'Indirect Data Write': 'indirect_data_', 'Indirect Data Read': 'indirect_data_',
}


def sdk_rows(path: pathlib.Path) -> list[tuple[int, int, str]]:
    """Return (address, size, name) of a model file's [control table] section."""
    lines = path.read_text(encoding='utf-8').splitlines()
    start = lines.index('[control table]') + 2   # skip the 'Address Size Data Name' header
    rows = []
    for line in lines[start:]:
        if line.strip():
            address, size, name = line.split('\t')[:3]
            rows.append((int(address), int(size), name.strip()))
    return rows


def listed_models() -> dict[int, str]:
    """Return dynamixel.model's model number -> model file name."""
    assert SDK is not None
    lines = (SDK / 'dynamixel.model').read_text(encoding='utf-8').splitlines()[1:]
    return {int(number): name for number, name in (line.split() for line in lines if line)}


def snake(sdk_name: str) -> str:
    """Return a model file's item name in snake_case."""
    return re.sub(r'[^0-9a-z]+', '_', sdk_name.lower()).strip('_')
