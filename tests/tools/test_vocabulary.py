"""The vocabulary file (spec/stringbt.md, section 5.1): a registry written out and read back
checks knowledge as the Python registry does, with the same codes and messages; old name-only
files keep working; ``load_vocabulary`` takes a file or a Python registry named
``module:callable`` and says in one line what is wrong with either."""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Annotated

import pytest
from pydantic import Field

import ktbt_proto as kp
from ktbt_proto.tools.vocabulary import load_vocabulary, parse_vocabulary, write_vocabulary
from ktbt_proto.validate import SupportsNames
from tests.door_robot import FLAT, MEMORY, VOCABULARY, door_blackboard, door_registry

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

REFUSED = [
    ("<a>(TurnHandle, degrees=120)", "SBT310"),
    ("<a>(TurnHandle, degrees=0)", "SBT310"),
    ('<a>(TurnHandle, degrees="60")', "SBT310"),
    ("<a>(TurnHandle, degrees=60.0)", "SBT310"),
    ('<c>(HandleSeen, side="up")', "SBT310"),
    ("<a>(TurnHandle)", "SBT311"),
    ("<a>(GraspHandle, force=3)", "SBT311"),
    ("<c>(DoorClosed, hard=true)", "SBT311"),
    ("<a>(Fly)", "SBT306"),
    ("<c>(DoorOpen)", "SBT305"),
]


def problems(text: str, registry: SupportsNames) -> list[str]:
    return [str(p) for p in kp.find_problems(kp.parse(text), registry)]


def test_the_registry_writes_the_vocabulary_file_and_reads_it_back() -> None:
    written = write_vocabulary(door_registry())
    assert written == VOCABULARY
    again = parse_vocabulary(written)
    assert write_vocabulary(again) == written
    assert again.conditions == door_registry().conditions
    assert again.actions == door_registry().actions


@pytest.mark.parametrize(("text", "code"), REFUSED, ids=[t for t, _ in REFUSED])
def test_a_file_refuses_what_the_python_registry_refuses_with_the_same_code(
    text: str, code: str
) -> None:
    python = problems(text, door_registry())
    from_file = problems(text, parse_vocabulary(VOCABULARY))
    assert [p.split()[1] for p in python] == [code]
    assert from_file == python


@pytest.mark.parametrize("text", [FLAT, MEMORY, '<c>(!HandleSeen, side="right")'])
def test_a_file_accepts_what_the_python_registry_accepts(text: str) -> None:
    assert problems(text, door_registry()) == []
    assert problems(text, parse_vocabulary(VOCABULARY)) == []


def test_declared_behaviours_check_and_merge_and_do_not_pretend_to_run(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Loaded from a file, a behaviour has no implementation: a tree over it compiles (an agent
    that only learns and exports runs one), a condition does not hold and an action fails,
    each said once in the log; a flag is a real blackboard read."""
    reg = parse_vocabulary(VOCABULARY.replace("flag = true", ""))
    bb = door_blackboard()
    live = kp.LiveTree(FLAT, reg, bb)
    with caplog.at_level(logging.WARNING, logger="ktbt.registry"):
        assert live.tick() is kp.FAILURE
        assert live.tick() is kp.FAILURE
    assert [r.getMessage() for r in caplog.records] == [
        "condition 'DoorClosed' is declared without an implementation here: it does not hold"
    ]
    acting = kp.LiveTree("<a>(Push)", reg, bb)
    assert acting.tick() is kp.FAILURE
    flags = kp.LiveTree("<c>(DoorClosed)", parse_vocabulary(VOCABULARY), bb)
    assert flags.tick() is kp.SUCCESS
    assert bb["log"] == []


def test_old_name_only_files_keep_working() -> None:
    reg = load_vocabulary(EXAMPLES / "sar_vocabulary.toml")
    tree = kp.parse((EXAMPLES / "sar_control.sbt").read_text(encoding="utf-8"))
    assert kp.find_problems(tree, reg) == []
    assert problems("<c>(TargetSeen, colour=2, anything=true)", reg) == []  # names only
    assert [p.split()[1] for p in problems("<a>(Fly)", reg)] == ["SBT306"]
    mixed = parse_vocabulary('conditions = ["Seen"]\n[actions.Go]\narguments.v = {}\n')
    assert problems("<sq><c>(Seen, x=1)<a>(Go, v=true)<e>", mixed) == []
    assert problems("<a>(Go)", mixed) == ["1:1: SBT311 action 'Go' needs argument 'v'"]


class Pose:
    """An application's own type: a Python registry can check it, a vocabulary file cannot."""


def test_an_annotation_the_file_cannot_hold_is_refused_in_one_line() -> None:
    reg = kp.Registry()

    @reg.action("MoveTo")
    def move(bb: kp.Blackboard, pose: Pose, speed: Annotated[float, Field(gt=0)] = 1) -> None:
        pass

    with pytest.raises(ValueError) as info:
        write_vocabulary(reg)
    assert str(info.value).startswith("action 'MoveTo', argument 'pose': Pose has no vocabulary")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        ("[actions.Go]\nspeed = 1\n", "actions.Go: unknown keys ['speed']"),
        ("[actions.Go]\narguments.v = { type = 'integer' }\n", "not one of int, float, str"),
        ("[actions.Go]\narguments.v = { ge = 1 }\n", "a range or choices needs a type"),
        ("[actions.Go]\narguments.v = { type = 'str', ge = 1 }\n", "for an int or a float"),
        ("[actions.Go]\narguments.v = { type = 'int', choices = [] }\n", "non-empty list of int"),
        ("[actions.Go]\narguments.v = { type = 'int', choices = [1, 'a'] }\n", "list of int"),
        ("[actions.Go]\narguments.v = 3\n", "arguments.v must be a table"),
        ("[actions.Go]\narguments.v = { required = 'no' }\n", "required must be true or false"),
        ("[actions.Go]\nflag = true\n", "a flag is a condition without arguments"),
        ("[actions.1Go]\n", "'1Go' is not a stringBT name"),
        ('actions = ["true"]\n', "'true' is not a stringBT name"),
        ("actions = 3\n", "'actions' must be a list of names or a table"),
        ("[actions]\nGo = 3\n", "actions.Go must be a table"),
    ],
)
def test_a_wrong_declaration_is_refused_in_one_line(
    tmp_path: Path, content: str, reason: str
) -> None:
    path = tmp_path / "robot.toml"
    path.write_text(content, encoding="utf-8")
    with pytest.raises(ValueError) as info:
        load_vocabulary(str(path))
    assert reason in str(info.value)
    assert str(info.value).startswith(f"registry {path}")
    assert "\n" not in str(info.value)


ROBOT = """
import ktbt_proto as kp

def make_registry():
    reg = kp.Registry()
    reg.add_action("Wave", lambda bb, times=1: kp.SUCCESS)
    return reg

REGISTRY = make_registry()
NOT_A_REGISTRY = 3

def returns_a_dict():
    return {}

def fails():
    raise RuntimeError("no arm\\nattached")
"""


@pytest.fixture
def robot_package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    package = tmp_path / "doorbot"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "robot.py").write_text(ROBOT)
    (package / "broken.py").write_text("import no_such_dependency_here\n")
    monkeypatch.chdir(tmp_path)  # the robot's own package, found from the current folder
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    for name in [m for m in sys.modules if m.startswith("doorbot")]:
        monkeypatch.delitem(sys.modules, name)
    return tmp_path


def test_a_python_registry_is_named_module_colon_callable(robot_package: Path) -> None:
    for spec in ("doorbot.robot:make_registry", "doorbot.robot:REGISTRY"):
        reg = load_vocabulary(spec)
        assert reg.has_action("Wave")
        assert problems("<a>(Wave, times=2)", reg) == []
        assert [p.split()[1] for p in problems("<a>(Wave, speed=2)", reg)] == ["SBT311"]


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (
            "doorbot.nothing:make",
            "registry doorbot.nothing:make: no module named 'doorbot.nothing'",
        ),
        (
            "doorbot.broken:make",
            "registry doorbot.broken:make: cannot import doorbot.broken: ModuleNotFoundError: "
            "No module named 'no_such_dependency_here'",
        ),
        ("doorbot.robot:missing", "registry doorbot.robot:missing: doorbot.robot has no 'missing'"),
        (
            "doorbot.robot:NOT_A_REGISTRY",
            "registry doorbot.robot:NOT_A_REGISTRY: NOT_A_REGISTRY is neither a Registry nor "
            "callable",
        ),
        (
            "doorbot.robot:returns_a_dict",
            "registry doorbot.robot:returns_a_dict: returns_a_dict() returned dict, not a Registry",
        ),
        (
            "doorbot.robot:fails",
            "registry doorbot.robot:fails: fails() failed: RuntimeError: no arm attached",
        ),
        (
            "doorbot/robot",
            "registry doorbot/robot: neither a vocabulary file (.toml) nor a Python registry "
            "named module:callable",
        ),
        ("missing.toml", "cannot read registry missing.toml: [Errno 2] No such file or directory"),
    ],
)
def test_a_bad_name_says_what_is_wrong_in_one_line(
    robot_package: Path, spec: str, message: str
) -> None:
    with pytest.raises(ValueError) as info:
        load_vocabulary(spec)
    assert str(info.value).startswith(message)
    assert "\n" not in str(info.value)


def test_a_vocabulary_file_loads_by_path(tmp_path: Path) -> None:
    path = tmp_path / "door.toml"
    path.write_text(VOCABULARY, encoding="utf-8")
    for spec in (path, str(path)):
        assert write_vocabulary(load_vocabulary(spec)) == VOCABULARY


def test_a_factory_s_signature_declares_its_arguments() -> None:
    class Wave:
        def __init__(self, times: Annotated[int, Field(ge=1)], name: str = "Wave") -> None:
            pass

    reg = kp.Registry()
    reg.declare_from("action", "Wave", Wave)
    assert problems("<a>(Wave, times=2)", reg) == []
    assert [p.split()[1] for p in problems("<a>(Wave, times=0)", reg)] == ["SBT310"]
    assert [p.split()[1] for p in problems('<a>(Wave, name="x")', reg)] == ["SBT311"]
    assert 'arguments.times = { type = "int", ge = 1 }' in write_vocabulary(reg)


def test_vocabulary_load(tmp_path: Path) -> None:
    path = tmp_path / "vocab.toml"
    path.write_text('conditions = ["Seen", "a.b"]\nactions = ["Go"]\n', encoding="utf-8")
    vocab = load_vocabulary(path)
    assert (vocab.conditions, vocab.actions) == (frozenset({"Seen", "a.b"}), frozenset({"Go"}))
    assert vocab.has_condition("Seen") and not vocab.has_condition("Go")
    assert vocab.has_action("Go") and not vocab.has_action("Seen")
    assert write_vocabulary(load_vocabulary(str(path))) == write_vocabulary(vocab)
    assert [
        (p.code.value, p.line, p.column)
        for p in kp.find_problems(kp.parse("<sq><c>(Seen)<a>(Go)<a>(Stop)<e>"), vocab)
    ] == [("SBT306", 1, 21)]


def test_vocabulary_load_missing_keys_default_to_empty(tmp_path: Path) -> None:
    path = tmp_path / "vocab.toml"
    path.write_text('actions = ["Go"]\n', encoding="utf-8")
    vocab = load_vocabulary(path)
    assert (vocab.conditions, vocab.actions) == (frozenset(), frozenset({"Go"}))


def test_example_registry_accepts_example_tree() -> None:
    vocab = load_vocabulary(EXAMPLES / "sar_vocabulary.toml")
    tree = kp.parse((EXAMPLES / "sar_control.sbt").read_text(encoding="utf-8"))
    assert kp.find_problems(tree, vocab) == []


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (None, "cannot read registry"),
        ("conditions = [", "cannot read registry"),
        (b"actions = ['\xff']\n", "cannot read registry"),
        ('conditions = "Seen"\n', "'conditions' must be a list of names"),
        ("actions = [1, 2]\n", "'actions' must be a list of names"),
        ('actions = ["Go", 3]\n', "'actions' must be a list of names"),
        ('conditions = []\nactions = []\nbehaviours = ["x"]\n', "unknown keys ['behaviours']"),
    ],
    ids=["missing", "bad-toml", "bad-utf8", "not-a-list", "ints", "mixed", "unknown-key"],
)
def test_vocabulary_load_rejects_bad_file(
    tmp_path: Path, content: str | bytes | None, reason: str
) -> None:
    path = tmp_path / "vocab.toml"
    if isinstance(content, str):
        path.write_text(content, encoding="utf-8")
    elif isinstance(content, bytes):
        path.write_bytes(content)
    with pytest.raises(ValueError, match="registry") as info:
        load_vocabulary(path)
    assert reason in str(info.value)
    assert "\n" not in str(info.value)
