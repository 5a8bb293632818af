"""
The driver's configuration: the one table of parameters, the types it fills, their validation.

The layer's face: the rest of the package imports config/ by this module alone, and it exports
what its clients use. Its modules, each of one job:

- params.py: PARAMS (top level) and JOINT_PARAMS (`<joint>.<key>`), each parameter's type,
  default, unit, range, description and when it is taken (ParamSpec); REGISTER_FAMILIES, the open
  families `<joint>.registers.<name>`. Validation, the ROS declarations, the runtime checks and
  docs/parameters.md (tools/param_table.py) all read them.
- driver_config.py: DriverConfig (a field per parameter, checked against PARAMS at import) and
  JointConfig, the validated configuration.
- checks.py: one value against its spec (check_spec), the diagnostics thresholds against each
  other, and ConfigError, which names the key at fault.
- joint_keys.py: one joint's keys read into a JointConfig and checked.
- model_fit.py: a joint's registers and mode against a servo model's control table.
- validation.py: validate(), a ROS parameter file's flat dictionary made a DriverConfig before
  the bus is touched, so that a bad file never moves a servo.
- files.py: check_parameter_file(), what ROS would refuse in a parameter file, said in a line.
"""

from dxl_servo_driver.config.checks import check_spec, check_thresholds, ConfigError
from dxl_servo_driver.config.driver_config import DriverConfig, field_of, JointConfig, replace
from dxl_servo_driver.config.files import check_parameter_file, ParameterFileError
from dxl_servo_driver.config.model_fit import check_joint_against, describe_register
from dxl_servo_driver.config.params import (
    JOINT_PARAMS, JOINT_PARAMS_BY_NAME, PARAMS, PARAMS_BY_NAME, ParamSpec, REGISTER_FAMILIES,
    RUNTIME_PARAMS, THRESHOLDS)
from dxl_servo_driver.config.validation import validate

__all__ = [
    'check_joint_against', 'check_parameter_file', 'check_spec', 'check_thresholds',
    'ConfigError', 'describe_register', 'DriverConfig', 'field_of', 'JOINT_PARAMS',
    'JOINT_PARAMS_BY_NAME', 'JointConfig', 'ParameterFileError', 'PARAMS', 'PARAMS_BY_NAME',
    'ParamSpec', 'REGISTER_FAMILIES', 'replace', 'RUNTIME_PARAMS', 'THRESHOLDS', 'validate',
]
