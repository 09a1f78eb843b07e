"""The algorithms' constructors stay in step with their base: every base argument in each signature, with the base's
annotation and default (but for the defaults an algorithm chooses on purpose), documented with ``:param:``, and
handed on by name to ``super().__init__``."""

from __future__ import annotations

import ast
import inspect
import re
import textwrap
from typing import Any

import pytest

from sb3_eps import GDQ, IQL, QMIX, VDN
from sb3_eps.common.off_policy import MultiAgentOffPolicyAlgorithm

#: The defaults an algorithm sets apart from its base's (its docstring says why).
OWN_DEFAULTS = {
    GDQ: {"learning_rate", "prioritized_replay", "team_reward_mode"},
    QMIX: {"learning_rate"},
    VDN: {"learning_rate", "advantage_learning"},
    IQL: set(),
}


def signature_problems(cls: type, base: type, own_defaults: set[str]) -> list[str]:
    """:return: what is out of step between ``cls``'s constructor and ``base``'s (empty: nothing)."""
    problems = []
    ours = inspect.signature(cls.__init__).parameters
    theirs = inspect.signature(base.__init__).parameters
    for name, parameter in theirs.items():
        if name not in ours:
            problems.append(f"{name} is missing")
            continue
        if str(ours[name].annotation) != str(parameter.annotation):
            problems.append(f"{name} is annotated {ours[name].annotation}, the base {parameter.annotation}")
        if (
            name not in own_defaults
            and ours[name].default is not parameter.default
            and ours[name].default != parameter.default
        ):
            problems.append(f"{name} defaults to {ours[name].default!r}, the base to {parameter.default!r}")
    if [name for name in ours if name in theirs] != [name for name in theirs if name in ours]:
        problems.append("the base's arguments are not in the base's order")
    documented = inspect.getdoc(cls) or ""
    problems += [f"{name} has no :param:" for name in ours if name != "self" and f":param {name}:" not in documented]
    if cls.__init__ is not base.__init__:
        passed = _super_init_keywords(cls)
        problems += [
            f"{name} is not passed by name to super().__init__"
            for name in theirs
            if name != "self" and passed.get(name) != name
        ]
    return problems


def _super_init_keywords(cls: type) -> dict[str, Any]:
    """:return: keyword -> the name passed for it in ``cls.__init__``'s ``super().__init__(...)`` call."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls.__init__)))
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "__init__"
            and isinstance(node.func.value, ast.Call)
            and getattr(node.func.value.func, "id", None) == "super"
        ):
            return {kw.arg: getattr(kw.value, "id", None) for kw in node.keywords if kw.arg is not None}
    return {}


@pytest.mark.parametrize("cls", [GDQ, QMIX, VDN, IQL], ids=lambda cls: cls.__name__)
def test_each_constructor_is_in_step_with_its_base(cls: type) -> None:
    base = cls.__mro__[1]
    assert signature_problems(cls, base, OWN_DEFAULTS[cls]) == []
    if base is not MultiAgentOffPolicyAlgorithm:  # VDN on QMIX: the shared base's arguments too
        assert signature_problems(cls, MultiAgentOffPolicyAlgorithm, OWN_DEFAULTS[cls]) == []


def test_the_check_finds_a_constructor_out_of_step() -> None:
    class Broken(MultiAgentOffPolicyAlgorithm):
        """:param policy: the policy"""

        def __init__(self, policy: str, env: Any = None, gamma: float = 0.5, n_steps: int = 3) -> None:
            super().__init__(policy=policy, env=env, gamma=0.9)

    problems = signature_problems(Broken, MultiAgentOffPolicyAlgorithm, set())
    assert "buffer_size is missing" in problems
    assert "gamma defaults to 0.5, the base to 0.99" in problems
    assert any(problem.startswith("policy is annotated") for problem in problems)
    assert "env has no :param:" in problems
    assert "gamma is not passed by name to super().__init__" in problems
    assert "n_steps is not passed by name to super().__init__" in problems
    assert "the base's arguments are not in the base's order" not in problems  # those present keep the order


def _param_docs(cls: type) -> dict[str, str]:
    """:return: argument -> its ``:param:`` text in ``cls``'s docstring (continuation lines joined)."""
    text = " ".join((inspect.getdoc(cls) or "").split())
    return {name: doc.strip() for name, doc in re.findall(r":param (\w+): (.*?)(?= :param |$)", text)}


def test_the_repeated_docs_of_a_shared_argument_say_the_same() -> None:
    """Each algorithm repeats the base's arguments in its docs (as SB3's algorithms do): the repeated lines stay equal
    where the algorithm keeps the base's default (its policy's arguments name its own policy)."""
    reference = _param_docs(IQL)
    for cls in (GDQ, QMIX, VDN):
        docs = _param_docs(cls)
        for name in set(reference) - OWN_DEFAULTS[cls] - {"policy_kwargs"}:
            assert docs[name] == reference[name], f"{cls.__name__}'s :param {name}: differs from IQL's"
