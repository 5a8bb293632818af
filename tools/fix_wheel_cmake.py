"""
Point the ROS wheels' CMake export files at this machine's Python.

The PyPI wheels of ROS 2 Jazzy were built in a manylinux image, and their CMake exports name that
image's paths (/opt/python/cp311-cp311/...), which CMake rejects as non-existent include
directories.
"""

import pathlib
import re
import sys
import sysconfig


def main(prefix: str) -> int:
    """Rewrite the stale paths under PREFIX/share; print how many files changed."""
    python_include = sysconfig.get_paths()['include']
    try:
        import numpy
        numpy_include = numpy.get_include()
    except ImportError:
        numpy_include = None
    pattern = re.compile(r'/opt/python/cp3\d+-cp3\d+/(include/python3\.\d+|lib/python3\.\d+/'
                         r'site-packages/numpy/_core/include)')

    def replace(match: 're.Match[str]') -> str:
        if match.group(1).startswith('include') or numpy_include is None:
            return python_include
        return numpy_include

    changed = 0
    for path in pathlib.Path(prefix, 'share').rglob('*.cmake'):
        text = path.read_text(errors='surrogateescape')
        new = pattern.sub(replace, text)
        if new != text:
            path.write_text(new, errors='surrogateescape')
            changed += 1
    print(f'setup: repaired the Python paths of {changed} CMake files in {prefix}/share')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1]))
