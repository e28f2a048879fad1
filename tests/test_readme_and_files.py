"""The README's promises: its Python snippets run, its commands exist, the Docker image's sources exist."""

from __future__ import annotations

import os
import re

from .conftest import ROOT


def test_readme_python_snippets_run(capsys):
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks
    cwd = os.getcwd()
    os.chdir(ROOT)
    namespace: dict = {}  # the snippets continue from each other, as a reader would type them
    try:
        for code in blocks:
            exec(compile(code, "README.md", "exec"), namespace)
    finally:
        os.chdir(cwd)
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "True"


def test_readme_service_snippets_compile():
    """Snippets that need a running service (marked `python notest`) are run in spirit by test_service; here they
    must at least be valid Python that names real client methods."""
    from replanner.client import Client

    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python notest\n(.*?)```", text, flags=re.S)
    assert blocks
    for code in blocks:
        compile(code, "README.md", "exec")
        for method in re.findall(r"client\.(\w+)\(", code):
            assert hasattr(Client, method), method


def test_readme_starts_with_the_two_commands():
    text = (ROOT / "README.md").read_text()
    first_block = re.search(r"```sh\n(.*?)```", text, flags=re.S).group(1)
    assert first_block.splitlines()[0].startswith("make demo")
    assert first_block.splitlines()[1].startswith("make test")
    makefile = (ROOT / "Makefile").read_text()
    assert re.search(r"^test:", makefile, flags=re.M) and re.search(r"^demo:", makefile, flags=re.M)
    assert "make test" in (ROOT / ".ci" / "run").read_text()


def test_dockerfile_copies_only_what_exists():
    text = (ROOT / "docker" / "Dockerfile").read_text()
    for src in re.findall(r"^COPY\s+(.+?)\s+\S+$", text, flags=re.M):
        for part in src.split():
            assert (ROOT / part).exists(), part
