"""The README's Python example runs, at a tiny budget, so the front door cannot rot.

The example is the first ``python`` block after the ``readme-example`` marker. Its budgets are scaled down by the
substitutions below, each of which must apply exactly once: an example whose ``learn`` call or evaluation changes
shape fails here instead of running its full budget.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MARKER = "<!-- readme-example"
TINY_BUDGET = {
    r"model\.learn\(\s*[\d_]+": "model.learn(600",
    r"n_eval_episodes=\d+": "n_eval_episodes=2",
}


def readme_example() -> str:
    text = (ROOT / "README.md").read_text()
    assert MARKER in text, "the README lost its readme-example marker"
    match = re.search(r"```python\n(.*?)```", text[text.index(MARKER) :], re.DOTALL)
    assert match is not None, "no python block after the readme-example marker"
    return match.group(1)


def test_the_readme_starts_with_the_two_commands() -> None:
    text = (ROOT / "README.md").read_text()
    first_block = re.search(r"```(\w*)\n(.*?)```", text, re.DOTALL)
    assert first_block is not None and first_block.group(1) == "bash"
    commands = [line.split("#")[0].strip() for line in first_block.group(2).splitlines()]
    assert commands == ["make run", "make test"]


def test_the_readme_example_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    code = readme_example()
    assert len(code.strip().splitlines()) <= 10
    for pattern, replacement in TINY_BUDGET.items():
        code, n_found = re.subn(pattern, replacement, code)
        assert n_found == 1, f"{pattern!r} matched {n_found} times in the README example"
    monkeypatch.chdir(tmp_path)  # the example saves its model in the working folder
    namespace: dict = {}
    exec(compile(code, "README.md example", "exec"), namespace)
    assert namespace["model"].num_timesteps >= 600
    assert (tmp_path / "gdq_2.zip").is_file()


def test_every_picture_and_local_link_in_the_docs_exists() -> None:
    """Each ``![...](path)`` and ``[...](path)`` of the README and docs/ that points into the repository names a file
    that is there (two results pictures were linked from the wrong folder until this test)."""
    missing = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            path = target.split("#")[0]
            if not path or re.match(r"^[a-z]+:", path):  # a web address or an anchor on the page
                continue
            if not (page.parent / path).exists() and not (ROOT / path).exists():
                missing.append(f"{page.relative_to(ROOT)}: {target}")
    assert not missing, "links to files that are not there:\n" + "\n".join(missing)
