"""Entry point of the ``skynav`` command."""

import sys


def main(argv=None) -> int:
    """Run ``skynav ARGS``; Ctrl-C anywhere (importing the libraries takes seconds) prints one line."""
    try:
        from .cli import main as cli_main  # inside the try: Ctrl-C while the libraries load is one line too

        return cli_main(argv)
    except KeyboardInterrupt:
        from .cli_common import interrupted  # loaded by the import above unless Ctrl-C came before it

        return interrupted()


if __name__ == "__main__":
    sys.exit(main())
