"""docs/api.md's worked example runs as written, in a fresh folder, on the simulator."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_worked_example_runs(tmp_path, monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), re.S)
    assert len(blocks) == 1
    (tmp_path / "protocols").mkdir()
    shutil.copy(ROOT / "protocols" / "esc-1100-1900.yaml", tmp_path / "protocols")
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("RIGTOOL_DB", raising=False)
    exec(compile(blocks[0], "docs/api.md", "exec"), {"__name__": "api_example"})
    out = capsys.readouterr().out
    assert "C_p_fwd = " in out and "command for 20 N forward" in out
