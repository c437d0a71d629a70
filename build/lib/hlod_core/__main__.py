import sys

from .cli import main as command_line

if __name__ == "__main__":
    sys.exit(command_line.main())
