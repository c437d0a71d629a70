"""pytest configuration: tests/ is on sys.path (rootdir-relative imports of helpers.py)."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
