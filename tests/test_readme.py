"""The README's Python blocks run as written (issue 56: its *Library* snippet did not), each at a smaller size: the
substitutions below shrink a recording or a preset and say so; nothing else in a block is changed."""

import dataclasses
import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# the long parts of a block, and what the test runs instead (a smaller recording, the smoke preset)
SMALLER = {'resolve_dataset("walker", "medium")': 'resolve_dataset("walker", "medium", transitions=3000, horizon=100)',
           'PRESETS["cpu"]': 'dataclasses.replace(PRESETS["smoke"], env="walker", dataset_transitions=3000, '
                             'episode_length=100, eval_episodes=2)'}


def python_blocks() -> list[str]:
    with open(os.path.join(ROOT, "README.md")) as f:
        return re.findall(r"```python\n(.*?)```", f.read(), re.S)


def test_the_readme_has_python_blocks_and_every_long_part_is_known():
    blocks = python_blocks()
    assert len(blocks) >= 2
    for b in blocks:
        for long in ('resolve_dataset("', 'PRESETS["'):
            for use in re.findall(re.escape(long) + r'[^)\]]*[)\]]', b):
                assert use in SMALLER, f"a long call without a smaller stand-in: {use}"


@pytest.mark.parametrize("i", range(len(python_blocks())))
def test_a_readme_python_block_runs(i, tmp_path, monkeypatch):
    code = python_blocks()[i]
    for long, small in SMALLER.items():
        code = code.replace(long, small)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"README.md python block {i + 1}", "exec"), {"dataclasses": dataclasses})
