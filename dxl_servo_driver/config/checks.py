"""A value checked against its parameter's spec (type, choices, range): ConfigError if not."""

import math
from typing import Any, Mapping

from dxl_servo_driver.config.params import ParamSpec
from dxl_servo_driver.errors import ConfigurationError


class ConfigError(ConfigurationError):
    """An invalid configuration; key names the parameter at fault."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f'parameter {key!r}: {message}')
        self.key = key


def check_type(key: str, value: Any, expected: type) -> Any:
    """Return the value as the expected type (an int is a float too); ConfigError if not."""
    if expected is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f'expected a number, got {value!r}')
        if not math.isfinite(float(value)):
            raise ConfigError(key, f'expected a finite number, got {value!r}')
        return float(value)
    if expected is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(key, f'expected an integer, got {value!r}')
        return value
    if expected is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f'expected true or false, got {value!r}')
        return value
    if expected is str:
        if not isinstance(value, str):
            raise ConfigError(key, f'expected a string, got {value!r}')
        return value
    if expected is list:
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ConfigError(key, f'expected a list of strings, got {value!r}')
        return list(value)
    raise AssertionError(expected)


def check_spec(spec: ParamSpec, value: Any, key: str = '') -> Any:
    """Return a parameter's value checked (type, choices, range); ConfigError names key if not."""
    key = key or spec.name
    value = check_type(key, value, spec.kind)
    if spec.choices and value not in spec.choices:
        if spec.noun:
            raise ConfigError(key, f'unknown {spec.noun} {value!r} (one of {list(spec.choices)})')
        raise ConfigError(key, f'{value!r} is not one of {list(spec.choices)}')
    unit = f' {spec.unit}' if spec.unit else ''
    if spec.minimum is not None and value < spec.minimum:
        raise ConfigError(key, f'{value} is below the minimum {spec.minimum:g}{unit} '
                          f'(range {spec.minimum:g}..{spec.maximum:g})')
    if spec.maximum is not None and value > spec.maximum:
        raise ConfigError(key, f'{value} is above the maximum {spec.maximum:g}{unit} '
                          f'(range {spec.minimum:g}..{spec.maximum:g})')
    return value


def check_thresholds(values: Mapping[str, Any]) -> None:
    """Raise ConfigError when the diagnostics thresholds contradict each other."""
    for low, high in (('temperature_warn', 'temperature_error'), ('voltage_low', 'voltage_high')):
        if values[low] > values[high]:
            raise ConfigError(low, f'{low} {values[low]:g} is above {high} {values[high]:g}')
