"""What every `dxl` command shares: exit statuses, the one error a command raises, its parser."""

import argparse

EXIT_OK = 0
EXIT_FAILED = 1       # the command ran and its answer is no (no servo, a check failed, a diff)
EXIT_USAGE = 2        # bad arguments or a bad file
EXIT_PORT = 3         # the port cannot be opened, or was lost
EXIT_OUTPUT = 4       # a file cannot be written
EXIT_INTERRUPTED = 130


class ToolError(Exception):
    """A command cannot go on: the message says why, `status` is the exit status."""

    def __init__(self, message: str, status: int = EXIT_FAILED) -> None:
        super().__init__(message)
        self.status = status


def add_command(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]', name: str,
                help_text: str, description: str, *examples: str) -> argparse.ArgumentParser:
    """Add one command's parser: its line in `dxl --help`, its description, its examples."""
    label = 'example' if len(examples) == 1 else 'examples'
    return sub.add_parser(
        name, help=help_text, description=description,
        epilog=f'{label}:\n' + '\n'.join(f'  {example}' for example in examples),
        formatter_class=argparse.RawDescriptionHelpFormatter)
