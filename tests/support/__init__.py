"""What the tests share: rigs, waits, frames and the helpers that start daemons.

Nothing here is collected as a test; each module says what it builds.
"""

from pathlib import Path

#: The repository's root (the checkout the tests run in).
REPO = Path(__file__).resolve().parents[2]
