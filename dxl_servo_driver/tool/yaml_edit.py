"""
A minimal editor of the driver's parameter files: set `<joint>.<key>` scalars, keep the rest.

A parameter file is written by people: comments, alignment and order carry meaning, and a tool
that rewrites it whole (PyYAML's dump) loses all of them. This editor works on lines: it finds
the `ros__parameters:` block (the one listing `joints` when there are several), the joint's
block in it, and there changes the value of a `key: value` line (its comment kept, at its column
when the new value leaves room) or inserts a `key: value` line at the end of the joint's block,
indented as its other keys. A joint given in the flat form (`elbow.offset: 0.2` directly under
ros__parameters) is changed in place the same way. Every other line stays byte-identical.

A joint written inline as a flow mapping on one line (`elbow: {id: 3, operating_mode:
position}`, as README.md's first example is) is first unfolded into the block mapping it means:
`elbow:` (its comment kept) and one `key: value` line per entry, each value's text as it was (a
nested flow mapping unfolded too, a flow sequence kept inline), indented as the file's other
joints indent their keys; then changed like any block.

What it cannot place it refuses (EditError, nothing changed): no block form it recognises (a
flow mapping continued on further lines, a value continued on further lines, a key given twice,
tabs), or an edited text that would not read back (PyYAML) as the old parameters with exactly
the changes.
"""

from dataclasses import dataclass
import difflib
import math
import re
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import yaml  # type: ignore[import-untyped]

SECTION_KEY = 'ros__parameters'
# A mapping line: indentation, key (plain or quoted), colon, then the rest (value and comment).
_KEY_LINE = re.compile(r"""^(?P<indent> *)(?P<key>'[^']*'|"[^"]*"|[^\s#'"\-][^#]*?|-[^\s#]"""
                       r"""[^#]*?)\s*:(?:[ \t]+(?P<rest>.*?))?\s*$""")
# How many decimals a float is written with: 0.1 mrad, well below a pulse (1.5 mrad on an X).
DECIMALS = 4


class EditError(ValueError):
    """The change cannot be placed in this file; the message says where and why."""


@dataclass(frozen=True)
class _Line:
    """One line of the file as the editor sees it."""

    text: str          # without its line break
    end: str           # its line break ('' on a last line without one)
    indent: int        # spaces before the content; -1 for a blank or comment-only line
    key: Optional[str]
    rest: str          # what follows the colon (value and comment), '' when nothing


def format_value(value: Any) -> str:
    """Return a value as a YAML scalar of the type ROS will read (a float always with a dot)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise EditError(f'{value} is not a finite number')
        text = f'{round(value, DECIMALS):.{DECIMALS}f}'.rstrip('0')
        text = text + '0' if text.endswith('.') else text
        return '0.0' if text in ('-0.0', '-0.') else text
    if isinstance(value, str) and re.fullmatch(r'[A-Za-z_][A-Za-z0-9_.\-]*', value) and \
            value.lower() not in ('true', 'false', 'yes', 'no', 'on', 'off', 'null', '~'):
        return value
    raise EditError(f'cannot write {value!r} as a parameter value')


def _unquote(key: str) -> str:
    if len(key) >= 2 and key[0] == key[-1] and key[0] in '\'"':
        return key[1:-1]
    return key


def _split_lines(text: str) -> List[_Line]:
    lines = []
    for raw in text.splitlines(keepends=True):
        body = raw.rstrip('\r\n')
        end = raw[len(body):]
        stripped = body.lstrip(' ')
        if not stripped or stripped.startswith('#'):
            lines.append(_Line(body, end, -1, None, ''))
            continue
        if stripped.startswith('\t') or '\t' in body[:len(body) - len(stripped) + 1]:
            raise EditError(f'line {len(lines) + 1}: a tab in the indentation (YAML indents '
                            'with spaces only)')
        match = _KEY_LINE.match(body)
        if match is None or stripped.startswith(('- ', '? ', '{', '[')):
            lines.append(_Line(body, end, len(body) - len(stripped), None, ''))
            continue
        lines.append(_Line(body, end, len(match.group('indent')),
                           _unquote(match.group('key').strip()), match.group('rest') or ''))
    return lines


def _split_comment(rest: str) -> Tuple[str, str]:
    """Return (value, the spaces and comment after it) of what follows a key's colon."""
    quote = ''
    for index, char in enumerate(rest):
        if quote:
            if char == quote:
                quote = ''
        elif char in '\'"' and (index == 0 or rest[index - 1] in ' \t'):
            quote = char
        elif char == '#' and (index == 0 or rest[index - 1] in ' \t'):
            # At 0 too: what follows a key's colon starts after a space (_KEY_LINE).
            value = rest[:index].rstrip()
            return value, rest[len(value):]
    return rest.rstrip(), ''


def _block_end(lines: Sequence[_Line], start: int, indent: int) -> int:
    """Return the index after the last line deeper than indent that follows line start."""
    end = start + 1
    index = start + 1
    while index < len(lines):
        line = lines[index]
        if line.indent == -1:
            # A comment indented into the block belongs to it; blank lines are decided later.
            stripped = line.text.lstrip(' ')
            if stripped and len(line.text) - len(stripped) <= indent:
                break
            index += 1
            continue
        if line.indent <= indent:
            break
        index += 1
        end = index
    return end


def _children(lines: Sequence[_Line], start: int, end: int) -> List[int]:
    """Return the indices of the direct key lines of the block lines[start + 1:end]."""
    keyed = [i for i in range(start + 1, end) if lines[i].indent >= 0]
    if not keyed:
        return []
    child_indent = min(lines[i].indent for i in keyed)
    return [i for i in keyed if lines[i].indent == child_indent and lines[i].key is not None]


def _sections(lines: Sequence[_Line]) -> List[Tuple[int, int]]:
    """Return (line, block end) of every `ros__parameters:` key."""
    found = []
    for index, line in enumerate(lines):
        if line.key == SECTION_KEY:
            if _split_comment(line.rest)[0]:
                raise EditError(f'line {index + 1}: {SECTION_KEY} is written inline (a flow '
                                'mapping): this editor changes block mappings only')
            found.append((index, _block_end(lines, index, line.indent)))
    return found


def _section(lines: Sequence[_Line]) -> Tuple[int, int]:
    found = _sections(lines)
    if not found:
        raise EditError(f'no "{SECTION_KEY}:" block in the file')
    if len(found) == 1:
        return found[0]
    with_joints = [(start, end) for start, end in found
                   if any(lines[i].key == 'joints' for i in _children(lines, start, end))]
    if len(with_joints) != 1:
        raise EditError(f'{len(found)} "{SECTION_KEY}:" blocks and {len(with_joints)} of them '
                        'list joints: cannot tell which one to change')
    return with_joints[0]


def _only(indices: Sequence[int], lines: Sequence[_Line], what: str) -> Optional[int]:
    if len(indices) > 1:
        raise EditError(f'{what} is given {len(indices)} times (lines '
                        f'{", ".join(str(i + 1) for i in indices)})')
    return indices[0] if indices else None


def _replace_value(line: _Line, number: int, value: str) -> str:
    """Return the line with its value replaced, its comment kept (at its column if it fits)."""
    old, comment = _split_comment(line.rest)
    if not old:
        raise EditError(f'line {number}: {line.key!r} has no value on its line')
    if old[0] in '[{|>&*!':
        raise EditError(f'line {number}: {line.key!r} is not a plain scalar ({old[:10]}...)')
    head = line.text[:len(line.text) - len(line.rest)]
    if comment:
        spaces = len(comment) - len(comment.lstrip(' \t'))
        padding = max(1, spaces + len(old) - len(value))
        return head + value + ' ' * padding + comment.lstrip(' \t')
    return head + value


def _set(lines: List[_Line], joint: str, key: str, value: str) -> Optional[Tuple[int, str]]:
    """
    Change lines in place for one `<joint>.<key>: value`.

    Return (index, text) of a line to insert before index, or None when a line was changed.
    """
    start, end = _section(lines)
    children = _children(lines, start, end)
    flat = _only([i for i in children if lines[i].key == f'{joint}.{key}'], lines,
                 f'{joint}.{key}')
    block = _only([i for i in children if lines[i].key == joint], lines, f'joint {joint!r}')
    target: Optional[int] = None
    inside: List[int] = []
    block_end = 0
    if block is not None:
        if _split_comment(lines[block].rest)[0]:
            raise EditError(f'line {block + 1}: joint {joint!r} is written inline (a flow '
                            'mapping or a value): this editor changes block mappings only')
        block_end = _block_end(lines, block, lines[block].indent)
        inside = _children(lines, block, block_end)
        target = _only([i for i in inside if lines[i].key == key], lines, f'{joint}.{key}')
    if target is not None and flat is not None:
        raise EditError(f'{joint}.{key} is given twice (lines {flat + 1} and {target + 1})')
    target = flat if target is None else target
    if target is not None:
        line = lines[target]
        after = _block_end(lines, target, line.indent)
        if after > target + 1:
            raise EditError(f'line {target + 1}: the value of {joint}.{key} continues on the '
                            'next lines: this editor changes one-line values only')
        text = _replace_value(line, target + 1, value)
        lines[target] = _Line(text, line.end, line.indent, line.key, text[line.indent:])
        return None
    if block is not None:
        if not inside:
            raise EditError(f'line {block + 1}: joint {joint!r} has no keys under it to place '
                            f'{key} beside')
        indent = lines[inside[0]].indent
        return block_end, ' ' * indent + f'{key}: {value}'
    dotted = [i for i in children if (lines[i].key or '').startswith(joint + '.')]
    if dotted:
        return dotted[-1] + 1, ' ' * lines[dotted[-1]].indent + f'{joint}.{key}: {value}'
    raise EditError(f'joint {joint!r} is not in the "{SECTION_KEY}:" block')


def _flow_split(body: str, at: str) -> List[str]:
    """
    Return body split at every `at` outside quotes and brackets (`at` ':' splits once).

    ':' counts only followed by a space or at the end, as YAML reads a flow entry's colon.
    """
    parts: List[str] = []
    depth, quote, start, index = 0, '', 0, 0
    while index < len(body):
        char = body[index]
        if quote:
            if char == '\\' and quote == '"':
                index += 1   # an escaped character of a double-quoted string
            elif char == quote:
                quote = ''
        elif char in '\'"' and (index == start or body[index - 1] in ' \t,[{:'):
            quote = char
        elif char in '[{':
            depth += 1
        elif char in ']}':
            depth -= 1
            if depth < 0:
                raise EditError('unbalanced brackets')
        elif char == at and depth == 0 and (
                at == ',' or index + 1 == len(body) or body[index + 1] in ' \t'):
            parts.append(body[start:index])
            start = index + 1
            if at == ':':
                break
        index += 1
    if quote or depth:
        raise EditError('an unclosed quote or bracket')
    parts.append(body[start:])
    return parts


def _flow_entries(text: str, indent: int, step: int) -> List[str]:
    """Return a one-line flow mapping `{k: v, ...}` as block lines at indent (values kept)."""
    body = text.strip()
    if not (body.startswith('{') and body.endswith('}')):
        raise EditError('not a flow mapping closed on its line')
    lines: List[str] = []
    for entry in _flow_split(body[1:-1], ','):
        if not entry.strip():
            continue   # `{}` or a trailing comma
        pair = _flow_split(entry.strip(), ':')
        if len(pair) != 2 or not pair[0].strip() or not pair[1].strip():
            raise EditError(f'{entry.strip()!r} is not a `key: value` entry')
        key, value = pair[0].strip(), pair[1].strip()
        if value.startswith('{'):
            lines.append(' ' * indent + f'{key}:')
            lines.extend(_flow_entries(value, indent + step, step))
        else:
            lines.append(' ' * indent + f'{key}: {value}')
    if not lines:
        raise EditError('an empty flow mapping')
    return lines


def _indent_step(lines: Sequence[_Line], first: Sequence[int]) -> int:
    """
    Return how far the file indents a block mapping's keys under it (2 if it shows none).

    The key lines `first` (the other joints) are looked at before the rest of the file.
    """
    for index in [*first, *range(len(lines) - 1)]:
        line = lines[index]
        if line.key is not None and not _split_comment(line.rest)[0]:
            deeper = next((other for other in lines[index + 1:] if other.indent >= 0), None)
            if deeper is not None and deeper.indent > line.indent:
                return deeper.indent - line.indent
    return 2


def _unfold(lines: List[_Line], joint: str) -> None:
    """Rewrite a joint written as a one-line flow mapping as its block mapping, in place."""
    start, end = _section(lines)
    children = _children(lines, start, end)
    block = _only([i for i in children if lines[i].key == joint], lines, f'joint {joint!r}')
    if block is None:
        return
    line = lines[block]
    value, comment = _split_comment(line.rest)
    if not value.startswith('{'):
        return
    if _block_end(lines, block, line.indent) > block + 1:
        raise EditError(f'line {block + 1}: joint {joint!r} is a flow mapping continued on the '
                        'next lines: write it as a block mapping (`' + joint + ':` and one key '
                        'a line under it)')
    try:
        step = _indent_step(lines, children)
        body = _flow_entries(value, line.indent + step, step)
    except EditError as exc:
        raise EditError(f'line {block + 1}: joint {joint!r} is written inline (a flow mapping) '
                        f'that this editor cannot unfold ({exc}): write it as a block mapping '
                        f'(`{joint}:` and one key a line under it)') from None
    new = [line.text[:len(line.text) - len(line.rest)].rstrip() + comment, *body]
    end_of_line = line.end or '\n'
    unfolded = []
    for number, text in enumerate(new):
        match = _KEY_LINE.match(text)
        assert match is not None
        unfolded.append(_Line(text, line.end if number == len(new) - 1 else end_of_line,
                              len(match.group('indent')), _unquote(match.group('key').strip()),
                              match.group('rest') or ''))
    lines[block:block + 1] = unfolded


def find_parameters(tree: Any) -> List[Dict[str, Any]]:
    """Return every `ros__parameters` mapping of a loaded parameter file, in file order."""
    found: List[Dict[str, Any]] = []
    if isinstance(tree, dict):
        for key, entry in tree.items():
            if key == SECTION_KEY and isinstance(entry, dict):
                found.append(entry)
            elif isinstance(entry, dict):
                found.extend(find_parameters(entry))
    return found


def flatten(tree: Mapping[str, Any], prefix: str = '') -> Dict[str, Any]:
    """Return nested parameters flattened as ROS does (`elbow.registers.profile_velocity`)."""
    flat: Dict[str, Any] = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def parameters_of(text: str) -> Dict[str, Any]:
    """Return the flat parameters of the section listing `joints` (or the only one)."""
    sections = find_parameters(yaml.safe_load(text))
    if len(sections) > 1:
        sections = [section for section in sections if 'joints' in section]
    if len(sections) != 1:
        raise EditError(f'{len(sections)} "{SECTION_KEY}:" blocks list joints: expected one')
    return flatten(sections[0])


def apply(text: str, changes: Mapping[str, Mapping[str, Any]]) -> str:
    """
    Return text with each `changes[joint][key] = value` set; EditError when one cannot be.

    The result is checked by reading it back: the same parameters as before but for the
    changes, which have exactly the values asked for.
    """
    try:
        before = parameters_of(text)
    except yaml.YAMLError as exc:
        raise EditError(f'the file is not valid YAML: {str(exc).splitlines()[0]}') from None
    lines = _split_lines(text)
    for joint in changes:
        _unfold(lines, joint)
    for joint, keys in changes.items():
        for key, value in keys.items():
            insert = _set(lines, joint, key, format_value(value))
            if insert is not None:
                index, body = insert
                end = lines[index - 1].end or '\n'
                if not lines[index - 1].end:   # the last line had no line break: it gets one
                    prev = lines[index - 1]
                    lines[index - 1] = _Line(prev.text, end, prev.indent, prev.key, prev.rest)
                match = _KEY_LINE.match(body)
                assert match is not None
                lines.insert(index, _Line(body, end, len(match.group('indent')),
                                          _unquote(match.group('key')), match.group('rest')))
    result = ''.join(line.text + line.end for line in lines)
    expected = dict(before)
    for joint, keys in changes.items():
        for key, value in keys.items():
            expected[f'{joint}.{key}'] = yaml.safe_load(format_value(value))
    try:
        after = parameters_of(result)
    except (yaml.YAMLError, EditError) as exc:
        raise EditError(f'the edited file would not read back: {exc}') from None
    if after != expected:
        wrong = sorted(k for k in set(after) | set(expected) if after.get(k) != expected.get(k))
        raise EditError('the edited file would not read back as intended (at '
                        f'{", ".join(wrong)}): the file\'s layout is one this editor cannot '
                        'change safely')
    return result


def unified_diff(old: str, new: str, path: str) -> str:
    """Return the unified diff of two versions of a file ('' when they are the same)."""
    return ''.join(difflib.unified_diff(old.splitlines(keepends=True),
                                        new.splitlines(keepends=True), path, path))
