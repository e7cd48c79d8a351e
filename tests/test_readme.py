"""The README's Python blocks run as written (issue 56: its *Library* snippet did not), each at a smaller size: the
substitutions below shrink a recording or a preset and say so; nothing else in a block is changed. Its shell blocks:
every command line of ours parses (flags that exist, values they take), and *Choose your trade-off* runs end to end
at the smoke size."""

import argparse
import dataclasses
import os
import re
import runpy
import shlex
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# the long parts of a block, and what the test runs instead (a smaller recording, the smoke preset)
SMALLER = {'resolve_dataset("walker", "medium")': 'resolve_dataset("walker", "medium", transitions=3000, horizon=100)',
           'PRESETS["cpu"]': 'dataclasses.replace(PRESETS["smoke"], env="walker", dataset_transitions=3000, '
                             'episode_length=100, eval_episodes=2)'}


NEEDS_RUN = 'load_policy("runs/walker-vec"'  # the block after *Choose your trade-off*'s commands: run there


def readme(name: str = "README.md") -> str:
    with open(os.path.join(ROOT, name)) as f:
        return f.read()


def python_blocks() -> list[str]:
    return [b for b in re.findall(r"```python\n(.*?)```", readme(), re.S) if NEEDS_RUN not in b]


def command_lines(text: str) -> list[list[str]]:
    """The ``python -m minsubdt_jax.*`` and ``python experiments/*.py`` commands of the shell blocks in ``text``, as
    argv (environment assignments, ``pip install ... &&`` and comments dropped; placeholders ``{a,b}`` skipped)."""
    out, blocks, lang = [], [], None
    for line in text.splitlines():  # fenced blocks, opened by ```lang and closed by ```
        if line.startswith("```"):
            lang = line[3:].strip() if lang is None else None
            if lang is not None:
                blocks.append("" if lang in ("", "bash") else None)
        elif lang is not None and blocks[-1] is not None:
            blocks[-1] += line + "\n"
    for block in filter(None, blocks):
        for line in block.replace("\\\n", " ").splitlines():
            line = (" " + line).split(" # ")[0].split("&&")[-1].strip().rstrip("&").strip()
            words = shlex.split(line) if line and "{" not in line else []
            while words and re.fullmatch(r"[A-Z_]+=.*", words[0]):
                words = words[1:]
            if words[:2] == ["python", "-m"] and words[2].startswith("minsubdt_jax") or (
                    words[:1] == ["python"] and len(words) > 1 and words[1].startswith(("experiments/", "benchmarks/"))):
                out.append(words)
    return out


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


class _Parsed(Exception):
    pass


# runpy warns that a module it runs as __main__ was imported before (by this process's earlier commands); a
# shell's fresh `python -m` does not
@pytest.mark.filterwarnings("ignore:.*found in sys.modules after import of package:RuntimeWarning")
def test_every_readme_command_parses(monkeypatch):
    """Each command of ours in the README's shell blocks gets through its parser: the training CLI's through
    ``train.parse_args`` (with its checks), the others' argparse (stopped right after parsing: nothing runs)."""
    from minsubdt_jax.train import parse_args

    commands = command_lines(readme()) + command_lines(readme("docs/GUIDE.md"))  # the README and its guide
    assert len(commands) >= 20 and any(c[2:3] == ["minsubdt_jax.evaluate"] for c in commands)
    original = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        raise _Parsed(original(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    for words in commands:
        if words[2:3] == ["minsubdt_jax.train"]:
            monkeypatch.setattr(argparse.ArgumentParser, "parse_args", original)
            parse_args(words[3:])
            monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
            continue
        monkeypatch.setattr(sys, "argv", [words[1] if words[1] != "-m" else words[2], *words[3 - (words[1] != "-m"):]])
        with pytest.raises(_Parsed):
            if words[1] == "-m":
                runpy.run_module(words[2], run_name="__main__", alter_sys=False)
            else:
                runpy.run_path(os.path.join(ROOT, words[1]), run_name="__main__")


def test_choose_your_trade_off_runs_as_written(tmp_path, monkeypatch, capsys):
    """*Choose your trade-off*: its commands in order (smoke preset, a small walker recording, 3 episodes), then the
    Python block after them, in one folder."""
    from minsubdt_jax.evaluate import main as evaluate
    from minsubdt_jax.train import main as train

    section = readme().split("## Choose your trade-off")[1].split("\n## ")[0].split("\n### ")[0]
    commands = command_lines(section)
    assert [c[2] for c in commands] == ["minsubdt_jax.train"] + ["minsubdt_jax.evaluate"] * 3
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    small = ["--preset", "smoke", "--dataset-transitions", "3000", "--episode-length", "100"]
    assert train([w for w in commands[0][3:] if w != "study" and w != "--preset"] + small) == 0
    for c in commands[1:]:
        assert evaluate(c[3:] + ["--episodes", "3"]) == 0
    assert len(os.listdir("runs/walker-vec/evaluations/minsubdt-vec")) == 3
    block = next(b for b in re.findall(r"```python\n(.*?)```", section, re.S))
    scope = {}
    exec(compile(block, "README.md Choose your trade-off", "exec"), scope)
    assert np_shape(scope["policy"](np_zeros(17))) == (6,)


def np_zeros(n):
    import numpy as np

    return np.zeros(n, np.float32)


def np_shape(x):
    return x.shape
