"""docs/cli.md is generated from the CLI; it must match the CLI of this commit."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_cli_reference_is_up_to_date():
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_cli_docs.py"), "--check"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"docs/cli.md is stale: run `python tools/gen_cli_docs.py`\n{proc.stdout}{proc.stderr}"


def test_cli_reference_lists_every_verb():
    text = (ROOT / "docs" / "cli.md").read_text()
    for verb in ("synth", "convert", "label", "train", "eval", "render", "export", "plot", "bench", "demo"):
        assert f"lift3d {verb}" in text, verb
