"""Every example in docs/protocol.md runs, in order, against a live serve + robot --kinematic (panda profile)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.service_helpers import Stack, node_session

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"
BLOCK = re.compile(r"```python\n(.*?)```", re.S)


def doc_blocks() -> list[str]:
    return BLOCK.findall(DOC.read_text())


def test_every_key_has_a_section_with_an_example():
    from replanner.transport.keys import KEYS

    sections = re.split(r"\n## ", DOC.read_text())[1:]
    for suffix in KEYS.values():
        owners = []
        for s in sections:
            title = re.findall(r"`([^`]+)`", s.split("\n", 1)[0])
            for tok in title:
                tok = tok.replace("<sensor>", "*")
                if tok == suffix or (tok.endswith("/*") and suffix.startswith(tok[:-1])):
                    owners.append(s)
        assert owners, f"docs/protocol.md has no section titled with `{suffix}`"
        assert all("```python" in s for s in owners), f"the section of `{suffix}` has no example"


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    s = Stack("panda", tmp_path_factory.mktemp("protocol_doc"))
    yield s
    s.stop()


def test_protocol_examples_run(stack):
    probe = node_session(stack.endpoint)
    try:
        stack.wait_alive(probe, "replanner/@v1/panda/alive")
    finally:
        probe.close()
    blocks = doc_blocks()
    assert len(blocks) >= 10
    namespace: dict = {}
    for i, code in enumerate(blocks):
        code = code.replace("tcp/127.0.0.1:7448", stack.endpoint)
        try:
            exec(compile(code, f"docs/protocol.md example {i + 1}", "exec"), namespace)
        except Exception as err:
            raise AssertionError(f"example {i + 1} failed: {err!r}\n{code}\n{stack.logs()}") from err
