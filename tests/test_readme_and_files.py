"""The README's promises: its Python snippets run, its commands exist, the Docker image's sources exist."""

from __future__ import annotations

import os
import re

from tests.conftest import ROOT


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
    from replanner.apps.client import Client

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
    for src in re.findall(r"^COPY\s+(?!--from)(.+?)\s+\S+$", text, flags=re.M):
        for part in src.split():
            assert (ROOT / part).exists(), part


def test_dockerfile_runs_as_a_user_and_starts_replanner():
    text = (ROOT / "docker" / "Dockerfile").read_text()
    final = text.split("\nFROM ")[-1]  # the last stage is the image
    assert final.startswith("python:3.11-slim") and "USER replanner" in final
    assert 'ENTRYPOINT ["replanner"]' in final


def test_compose_file_parses_and_its_commands_exist():
    """No Docker engine here: the compose file must parse, point at real files, and run real commands."""
    import subprocess

    import yaml

    from tests.service_helpers import replanner_cmd

    compose = yaml.safe_load((ROOT / "docker" / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"router", "service", "sim", "client"}
    assert services["router"]["image"].startswith("eclipse/zenoh:")
    for volume in services["router"]["volumes"]:
        assert (ROOT / "docker" / volume.split(":")[0]).resolve().exists(), volume
    build = services["service"]["build"]
    assert (ROOT / "docker" / build["context"] / build["dockerfile"]).resolve().exists()
    for name in ("service", "sim", "client"):
        cmd = services[name]["command"]
        assert cmd[cmd.index("--zenoh-config") + 1] == "client"  # through the router, in client mode
        # the image's entry point is `replanner`: the same arguments must parse on the host
        out = subprocess.run(replanner_cmd(*cmd, "--help"), capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, (cmd, out.stderr)


def test_secure_compose_file_uses_the_identities_certs_writes(tmp_path):
    """docker/compose.secure.yaml: its services exist in compose.yaml, each runs with an identity that the command in
    its header writes (run here into tmp), and its commands parse."""
    import re
    import shlex
    import subprocess

    import yaml

    from tests.service_helpers import replanner_cmd

    text = (ROOT / "docker" / "compose.secure.yaml").read_text()
    secure = yaml.safe_load(text)["services"]
    assert set(secure) <= set(yaml.safe_load((ROOT / "docker" / "compose.yaml").read_text())["services"])
    certs_line = re.search(r"#\s+(replanner certs .*)", text).group(1)
    argv = shlex.split(certs_line)
    out = subprocess.run(replanner_cmd(*argv[1:]), cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    for name, svc in secure.items():
        assert "../certs:/certs:ro" in svc["volumes"], name
        cmd = svc["command"]
        conf = cmd[cmd.index("--config" if name == "router" else "--zenoh-config") + 1]
        assert conf.startswith("/certs/") and (tmp_path / "certs" / conf.removeprefix("/certs/")).exists(), conf
        written = (tmp_path / "certs" / conf.removeprefix("/certs/")).read_text()
        assert '"/certs/ca.pem"' in written  # paths as the containers see them
        if name != "router":
            out = subprocess.run(replanner_cmd(*cmd, "--help"), capture_output=True, text=True, timeout=60)
            assert out.returncode == 0, (cmd, out.stderr)


def test_every_package_is_installed():
    """A non-editable install (the Docker image) gets only the packages pyproject lists."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {
        ".".join(p.parent.relative_to(ROOT).parts).replace("services", "replanner_services", 1)
        for p in (ROOT / "replanner").rglob("__init__.py")
    } | {"replanner_services", "replanner_configs"}
    assert found <= listed, sorted(found - listed)
