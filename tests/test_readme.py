"""The README's Python example and shell commands work as written."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")


def _blocks(lang):
    return re.findall(rf"```{lang}\n(.*?)```", README, flags=re.S)


def test_readme_python_example_runs(capsys):
    blocks = _blocks("python")
    assert blocks, "the README has no python example"
    for code in blocks:
        exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert "Gaussian(mean=" in out
    for shown in _blocks("text"):  # the output the README shows is what the examples print
        assert shown in out


def test_readme_commands(tmp_path):
    commands = [line for block in _blocks("bash") for line in block.splitlines()]
    assert any(c.startswith("pip install") for c in commands)
    assert any(c.startswith("python -m pytest") for c in commands)
    gaussfuse = [c.split() for c in commands if c.startswith("gaussfuse ")]
    assert [c[1] for c in gaussfuse] == ["demo", "filter", "fit"]
    bindir = Path(sys.executable).parent
    for argv in gaussfuse:
        argv = [a if not a.startswith("examples/") else str(ROOT / a) for a in argv]
        exe = bindir / "gaussfuse"
        cmd = [str(exe)] + argv[1:] if exe.exists() else [sys.executable, "-m", "gaussfuse"] + argv[1:]
        done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
    assert (tmp_path / "gaussfuse-demo.png").stat().st_size > 10_000
    assert (tmp_path / "estimates.csv").read_text().startswith("t,x,y,vx,vy,std_x")
    assert (tmp_path / "estimates.png").stat().st_size > 10_000
    assert "[model]" in (tmp_path / "nile-fitted.toml").read_text()
