"""A parameter file checked for what ROS would refuse, before ROS reads it."""

from typing import Any, Mapping

from dxl_servo_driver.errors import ConfigurationError
import yaml  # type: ignore[import-untyped]


class ParameterFileError(ConfigurationError):
    """A parameter file ROS could not read; the message names the file and, if any, the key."""


_YAML_KINDS = ((bool, 'bool'), (int, 'integer'), (float, 'double'), (str, 'string'))


def _kind(value: Any) -> str:
    for python_type, name in _YAML_KINDS:   # bool first: it is an int too
        if isinstance(value, python_type):
            return name
    return type(value).__name__


def check_parameter_file(path: str) -> None:
    """
    Raise ParameterFileError when ROS could not read this parameter file, saying why in a line.

    ROS parses parameter files in C and answers a bad one with a traceback (or an error about
    a parameter it typed PARAMETER_NOT_SET); this checks first what it would refuse: a missing
    or unreadable file, invalid YAML (tabs included), no `<node>: ros__parameters:` mapping,
    empty lists and mappings (ROS cannot give them a type), lists of lists, mixed-type lists.
    """
    try:
        with open(path, encoding='utf-8') as stream:
            text = stream.read()
    except FileNotFoundError:
        raise ParameterFileError(f'parameter file {path} does not exist') from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParameterFileError(f'parameter file {path} cannot be read: {exc}') from None
    try:
        tree = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        lines = text.splitlines()
        hint = ''
        if mark is not None and mark.line < len(lines) and '\t' in lines[mark.line]:
            hint = ' (a tab: YAML indents with spaces only)'
        raise ParameterFileError(f'parameter file {path}: invalid YAML{where}: {problem}'
                                 f'{hint}') from None
    if tree is None:
        return   # an empty file sets nothing; the configuration check says what is missing
    if not isinstance(tree, dict):
        raise ParameterFileError(
            f'parameter file {path}: the top level must map node names (e.g. /**) to '
            f'"ros__parameters:", not a {_kind(tree)}')
    _check_node_entries(path, tree, '')


def _check_node_entries(path: str, tree: Mapping[Any, Any], prefix: str) -> None:
    for key, entry in tree.items():
        where = f'{prefix}{key}'
        if not isinstance(entry, dict):
            raise ParameterFileError(
                f'parameter file {path}: {where!r} needs "ros__parameters:" under it (a node '
                'name, then ros__parameters, then the parameters)')
        if 'ros__parameters' in entry:
            params = entry['ros__parameters']
            if params is None:
                continue
            if not isinstance(params, dict):
                raise ParameterFileError(f'parameter file {path}: {where}.ros__parameters must '
                                         'be a mapping of parameter names to values')
            _check_values(path, params, '')
        else:
            _check_node_entries(path, entry, where + '/')   # namespaces may nest


def _check_values(path: str, params: Mapping[Any, Any], prefix: str) -> None:
    for key, value in params.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            if not value:
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: an empty mapping is not a '
                    'parameter (ROS cannot give it a type); leave the key out')
            _check_values(path, value, name + '.')
        elif isinstance(value, list):
            if not value:
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: an empty list has no type '
                    'ROS can give it; list at least one element or leave the key out')
            kinds = sorted({_kind(element) for element in value})
            if any(isinstance(element, (list, dict)) for element in value):
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: a list of lists or mappings '
                    'is not a ROS parameter')
            if len(kinds) > 1:
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: a list mixing '
                    f'{" and ".join(kinds)}: the elements of a ROS list all have one type')
