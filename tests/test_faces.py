"""Small faces (issue 49, item 3): the online policy keeps the agent's verbs and shows what it knows
through one read-only snapshot and one record; the simulator reads the policy through a few names."""

import ast
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_POLICY_NAMES, MAX_POLICY_LINES, MAX_SIM_NAMES = 12, 450, 10
VERBS = {"reset", "act", "observe", "update_world", "relocalise", "prepare", "start_belief", "from_design"}


def _public(cls) -> set[str]:
    return {n for n in dir(cls) if not n.startswith("_")}


def test_the_policy_keeps_its_verbs_and_few_names():
    from firmtool.online.policy import Policy

    names = _public(Policy)
    assert VERBS <= names and {"state", "record"} <= names
    assert len(names) <= MAX_POLICY_NAMES, sorted(names)
    lines = len((ROOT / "firmtool" / "online" / "policy.py").read_text().splitlines())
    assert lines <= MAX_POLICY_LINES, lines


def _policy_names_read(folder: Path, public: set[str]) -> set[str]:
    """The Policy's public names read in ``folder``'s modules: attributes of a name bound to a policy
    (a parameter annotated ``Policy``, or a name that says policy)."""
    read: set[str] = set()
    for path in sorted(folder.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for fn in [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]:
            bound = {a.arg for a in fn.args.args + fn.args.kwonlyargs
                     if a.annotation is not None and "Policy" in ast.unparse(a.annotation)}
            for node in ast.walk(fn):
                if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
                    if (node.value.id in bound or "policy" in node.value.id.lower()) and node.attr in public:
                        read.add(node.attr)
    return read


def test_the_simulator_reads_few_names_of_the_policy():
    from firmtool.online.policy import Policy

    read = _policy_names_read(ROOT / "firmtool" / "sim", _public(Policy))
    assert {"act", "observe", "reset"} <= read  # the counter sees the loop (it would see nothing if broken)
    assert len(read) <= MAX_SIM_NAMES, sorted(read)


def test_the_counter_counts_what_a_module_reads(tmp_path):
    """The count above is not vacuous: a module that reads a name of the policy is counted."""
    (tmp_path / "m.py").write_text("def f(agent: 'Policy', x):\n    agent.act()\n    x.observe()\n"
                                   "    return my_policy.state, agent.nothing\n")
    assert _policy_names_read(tmp_path, {"act", "observe", "state", "record"}) == {"act", "state"}


@pytest.fixture(scope="module")
def smoke(smoke_roadmap):
    import firmtool as ft

    return ft.open_roadmap(smoke_roadmap[0]).solution()


def test_the_snapshot_is_read_only_and_a_copy(smoke):
    """``state`` is frozen and holds copies: a later control period moves the policy, not the snapshot;
    ``record`` says what the run did, as the episode the simulator fills from it."""
    import dataclasses

    import firmtool as ft

    policy = ft.Policy(smoke, rng=0)
    before = policy.state
    assert before.done and before.mean is None and before.steps == 0 and not policy.record.events
    policy.reset()
    first = policy.state
    assert first.steps == 0 and first.node == 0 and np.array_equal(first.mean, smoke.roadmap.execution_design.centers[0])
    with pytest.raises(dataclasses.FrozenInstanceError):
        first.steps = 3  # type: ignore[misc]
    for _ in range(5):
        u = policy.act()
        policy.observe(_measure(policy, u))
    now = policy.state
    assert now.steps == 5 and first.steps == 0  # the old snapshot did not move
    assert not np.array_equal(now.mean, first.mean)
    rec = policy.record
    assert rec.events[0].kind == ft.EventKind.START and len(rec.timing["act"]) == 5
    assert rec.timing_summary().act.calls == 5


def _measure(policy, u):
    """The measurement of the snapshot's mean (noise-free): enough to move the belief."""
    st = policy.state
    model = st.problem.model
    x = model.f(st.mean[None], u[None])[0]
    return x if st.problem.perfect else model.h(x[None])[0]
