"""The ``ktbt`` command line, run as a user runs it: a real process, real files."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from ktbt_proto.tools.cli.options import DEMO_NOTE
from tests.door_robot import FLAT, VOCABULARY

pytestmark = pytest.mark.network  # every test runs the ktbt command as a process

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"

UGLY = "<sl><sq> <c>(X)   # why\n<a>(Y)<e><a>(Z)<e>"
PRETTY = "<sl>\n    <sq>\n        <c>(X)  # why\n        <a>(Y)\n    <e>\n    <a>(Z)\n<e>\n"


def ktbt(*args: str, stdin: bytes | None = None, cwd: Path | None = None) -> tuple[int, str, str]:
    proc = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", *args],
        input=stdin,
        capture_output=True,
        cwd=cwd or ROOT,
        timeout=120,
    )
    return proc.returncode, proc.stdout.decode(), proc.stderr.decode()


def test_fmt_rewrites_in_place(tmp_path: Path) -> None:
    f = tmp_path / "tree.sbt"
    f.write_text(UGLY)
    code, _, err = ktbt("fmt", str(f))
    assert code == 0
    assert f.read_text() == PRETTY
    assert f"reformatted {f}" in err
    code, _, err = ktbt("fmt", str(f))
    assert code == 0 and "1 file left unchanged" in err


def test_fmt_check_and_diff_write_nothing(tmp_path: Path) -> None:
    f = tmp_path / "tree.sbt"
    f.write_text(UGLY)
    code, out, err = ktbt("fmt", "--check", str(f))
    assert (code, out) == (1, "")
    assert f"would reformat {f}" in err
    code, out, _ = ktbt("fmt", "--diff", str(f))
    assert code == 0
    assert out.startswith(f"--- {f}\t(original)\n+++ {f}\t(formatted)\n")
    assert "+        <c>(X)  # why\n" in out
    assert f.read_text() == UGLY
    code, _, _ = ktbt("fmt", "--check", "--diff", str(f))
    assert code == 1


def test_fmt_stdin_to_stdout() -> None:
    assert ktbt("fmt", "-", stdin=UGLY.encode())[:2] == (0, PRETTY)
    code, out, _ = ktbt("fmt", "--compact", "-", stdin=UGLY.encode())
    assert (code, out) == (0, "<sl><sq><c>(X)<a>(Y)<e><a>(Z)<e>\n")
    assert ktbt("fmt", "--check", "-", stdin=PRETTY.encode())[0] == 0
    assert ktbt("fmt", "--check", "-", stdin=UGLY.encode())[0] == 1


def test_fmt_errors_exit_123_and_touch_nothing(tmp_path: Path) -> None:
    good = tmp_path / "good.sbt"
    good.write_text(UGLY)
    bad = tmp_path / "bad.sbt"
    bad.write_text("<sq>\n  <a>(X")
    code, _, err = ktbt("fmt", str(bad), str(good), str(tmp_path / "missing.sbt"))
    assert code == 123
    lines = err.splitlines()
    assert (
        f"error: cannot format {bad}:2:8: SBT104 input ends inside <a> at 2:3; expected ')', ','"
        in lines
    )
    assert f"error: cannot format {tmp_path / 'missing.sbt'}: No such file or directory" in lines
    assert bad.read_text() == "<sq>\n  <a>(X"
    assert good.read_text() == PRETTY  # the good file is still formatted
    assert "Traceback" not in err


def test_fmt_directory_and_non_utf8(tmp_path: Path) -> None:
    (tmp_path / "a.sbt").write_text(UGLY)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.sbt").write_bytes(b"<a>(X)\xff")
    (tmp_path / "notes.txt").write_text("not a tree")
    code, _, err = ktbt("fmt", str(tmp_path))
    assert code == 123
    assert f"error: cannot format {tmp_path / 'sub' / 'b.sbt'}:1:7: SBT100" in err
    assert (tmp_path / "a.sbt").read_text() == PRETTY
    assert "notes.txt" not in err


def test_check_reports_every_problem(tmp_path: Path) -> None:
    f = tmp_path / "t.sbt"
    f.write_text("<sq>\n    <neg><e>\n    <pl>(3)<a>(Go)<e>\n    <a>(Fly)\n<e>\n")
    code, out, _ = ktbt("check", str(f))
    assert code == 1
    assert out.splitlines() == [
        f"{f}:2:5: SBT301 <neg> needs exactly one child, not 0",
        f"{f}:3:5: SBT308 parallel threshold 3 is not in 1..1",
    ]
    code, out, _ = ktbt("check", "--vocabulary", str(EXAMPLES / "sar_vocabulary.toml"), str(f))
    assert f"{f}:3:12: SBT306 unknown action 'Go'" in out.splitlines()
    assert f"{f}:4:5: SBT306 unknown action 'Fly'" in out.splitlines()


def test_check_clean_files_and_bad_inputs(tmp_path: Path) -> None:
    code, out, _ = ktbt(
        "check",
        "--vocabulary",
        str(EXAMPLES / "sar_vocabulary.toml"),
        str(EXAMPLES / "sar_control.sbt"),
        str(EXAMPLES / "paper_control.sbt"),
    )
    assert code == 0  # the flat items' re-run trap is a warning, not a problem
    assert all(" SBT502 warning: " in line for line in out.splitlines())
    code, out, err = ktbt("check", str(tmp_path / "nope.sbt"))
    assert (
        code == 1
        and out == f"{tmp_path / 'nope.sbt'}: error: cannot read: No such file or directory\n"
    )
    code, out, _ = ktbt("check", "-", stdin=b"<sq><a>(X)<e><e>")
    assert (code, out) == (1, "<stdin>:1:14: SBT105 <e> closes nothing: no node is open\n")
    reg = tmp_path / "reg.toml"
    reg.write_text("conditions = 3\n")
    code, _, err = ktbt("check", "--vocabulary", str(reg), str(EXAMPLES / "sar_control.sbt"))
    assert code == 2 and "'conditions' must be a list of names" in err and "Traceback" not in err
    assert err.startswith(f"error: --vocabulary: registry {reg}: ") and len(err.splitlines()) == 1


@pytest.mark.parametrize("fmt", ["outline", "dot", "mermaid"])
def test_show(fmt: str) -> None:
    code, out, _ = ktbt("show", "--format", fmt, str(EXAMPLES / "sar_control.sbt"))
    assert code == 0
    first = {"outline": "Selector", "dot": "digraph stringbt {", "mermaid": "flowchart TD"}[fmt]
    assert out.splitlines()[0] == first
    assert "RandomWalk" in out


def test_show_bad_input() -> None:
    code, out, err = ktbt("show", "-", stdin=b"<sq>")
    assert code == 1 and out == ""
    assert err.startswith("<stdin>:1:5: SBT104 input ends inside <sq> opened at 1:1")


def test_tour_runs() -> None:
    code, out, _ = ktbt("tour")
    assert code == 0
    assert "<sl><sq><c>(_collisionDetectedF)<a>(CollisionAvoidance)<e>" in out
    assert "SBT306 unknown action 'Teleport'" in out
    assert "r2 asked, r1 answered" in out and "heads for zone 2" in out
    rows = sum(max(1, -(-len(line) // 80)) for line in out.splitlines())
    assert rows <= 40, f"the tour takes {rows} rows of an 80-column terminal, not one screen"
    code, out, _ = ktbt("tour", cwd=Path(os.sep))  # the examples come with the package
    assert code == 0 and "r2 asked, r1 answered" in out
    code, _, err = ktbt("tour", "--examples", str(Path(os.sep) / "nonexistent"))
    assert code == 1 and "not found" in err


def test_convert_both_ways(tmp_path: Path) -> None:
    xml = tmp_path / "tree.xml"
    code, _, err = ktbt("convert", str(EXAMPLES / "sar_control.sbt"), str(xml))
    assert code == 0, err
    assert '<root BTCPP_format="4" main_tree_to_execute="MainTree">' in xml.read_text()
    back = tmp_path / "back.sbt"
    assert ktbt("convert", str(xml), str(back))[0] == 0
    original = (EXAMPLES / "sar_control.sbt").read_bytes()
    assert (
        ktbt("fmt", "--compact", "-", stdin=back.read_bytes())[1]
        == ktbt("fmt", "--compact", "-", stdin=original)[1]
    )
    bad = tmp_path / "bad.xml"
    bad.write_text('<root BTCPP_format="4">\n  <BehaviorTree ID="MainTree">\n    <Foo/>\n')
    code, _, err = ktbt("convert", str(bad), str(tmp_path / "x.sbt"))
    assert code == 1 and err.startswith(f"error: cannot convert {bad}:"), err
    assert "Traceback" not in err
    code, _, err = ktbt("convert", str(bad), str(tmp_path / "x.txt"))
    assert code == 1 and "Traceback" not in err


def test_hostile_inputs_get_one_line_not_a_traceback(tmp_path: Path) -> None:
    s = tmp_path / "s.sbt"
    s.write_text('<a>(X, s="\\ud800")\n')
    code, _, err = ktbt("fmt", str(s))
    assert code == 0 and "Traceback" not in err
    assert s.read_text() == '<a>(X, s="\\ud800")\n'  # still escaped: UTF-8 cannot carry it
    code, out, _ = ktbt("check", str(s))
    assert code == 1 and "SBT310" in out
    code, out, _ = ktbt("check", "/dev/zero")  # refused after reading just past the limit
    assert (code, out) == (
        1,
        "/dev/zero:1:1: SBT201 input is 4000001 bytes, the limit is 4000000\n",
    )
    proc = subprocess.run(
        [sys.executable, "-m", "ktbt_proto", "fmt", "-"],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert proc.returncode == 123 and "Traceback" not in proc.stderr


def test_fmt_writes_through_symlinks_and_keeps_permissions(tmp_path: Path) -> None:
    target = tmp_path / "t.sbt"
    target.write_text(UGLY)
    link = tmp_path / "link.sbt"
    target.chmod(0o640)
    link.symlink_to(target)
    assert ktbt("fmt", str(link))[0] == 0
    assert link.is_symlink() and target.read_text() == PRETTY
    assert target.stat().st_mode & 0o777 == 0o640  # the file's permissions are kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.sbt", "t.sbt"]


def test_merge_refuses_to_write_an_invalid_tree(tmp_path: Path) -> None:
    control = tmp_path / "c.sbt"
    control.write_text("<sl><sq><k>(new)<e><e><a>(R)<e>")
    code, out, err = ktbt("merge", str(control), "-", stdin=b"<sq><k>(new)<e><a>(Z)<e>")
    assert (code, out) == (1, "") and "SBT304" in err
    code, _, err = ktbt("merge", str(control), "-", "--when", ",,", stdin=b"<a>(Z)")
    assert code == 2 and "expected a condition before ','" in err  # usage: exit 2
    code, _, err = ktbt("merge", str(control), "-", "--when", " ", stdin=b"<a>(Z)")
    assert code == 2 and "names no condition" in err


@pytest.mark.parametrize(
    ("sequence", "caret", "code"),
    [
        ("TargetSeen(colour=100)", "                  ^", "SBT310"),  # under the value
        ("Carrying, TargetSeen(colour = 100)", "                              ^", "SBT310"),
        ("TargetSeen(color=2)", "           ^", "SBT311"),  # under the argument's name
        ("Carrying, Nope", "          ^", "SBT305"),  # under the unknown condition
    ],
)
def test_peer_run_refuses_at_start_a_sequence_its_own_registry_refuses(
    sequence: str, caret: str, code: str
) -> None:
    """It could never accept an answer to it: exit 2 before joining any network, the error in
    one line, a caret under the part of the argument at fault (no asking for its duration)."""
    status, out, err = ktbt("peer", "run", "--sequence", sequence, "--duration", "600")
    assert status == 2 and out == ""
    lines = err.splitlines()
    assert lines[0] == DEMO_NOTE  # neither --vocabulary nor --control: the demo robot
    assert lines[1].startswith(f"error: --sequence {sequence!r}: {code} ")
    assert lines[2:] == [f"    {sequence}", f"    {caret}"]
    assert "Traceback" not in err


def test_peer_commands_take_fixed_choices_as_choices() -> None:
    for args in (
        ["run", "--mode", "router"],
        ["serve", "--knowledge", "x.sbt", "--overhear", "loud"],
        ["ask", "--sequence", "A", "--policy", "x"],
    ):
        status, _, err = ktbt("peer", *args)
        assert status == 2 and "is not one of" in err, err


def test_check_with_a_vocabulary_prints_the_rerun_warning_without_failing(tmp_path: Path) -> None:
    door, skill = tmp_path / "door.toml", tmp_path / "door.sbt"
    door.write_text(VOCABULARY)
    skill.write_text(f"<k>(prior)\n    {FLAT}\n<e>\n")
    for spec in (str(door), "tests.door_robot:door_registry"):
        code, out, err = ktbt("check", "--vocabulary", spec, str(skill))
        assert code == 0, err
        [line] = out.splitlines()
        assert line.startswith(f"{skill}:2:") and " SBT502 warning: " in line


# The command-line rows of the mistakes table: one line naming the option, exit 2.
MISTAKES = [
    (["kb", "show", str(EXAMPLES / "knowledge" / "colours.sbt")],
     "error: FILE {examples}/knowledge/colours.sbt: a stringBT file, not a saved knowledge "
     "base; kb show reads the JSON that peer run --save writes"),
    (["peer", "run", "--vocabulary", "nope.toml"],
     "error: --vocabulary: nope.toml not found (a FILE.toml, or module:callable)"),
    (["peer", "serve", "--knowledge", "x.sbt", "--vocabulary", "no_such_robot:make"],
     "error: --vocabulary: registry no_such_robot:make: no module named 'no_such_robot'"),
    (["check", "--vocabulary", "tests.door_robot:no_registry", "x.sbt"],
     "error: --vocabulary: registry tests.door_robot:no_registry: tests.door_robot has no "
     "'no_registry'"),
    (["peer", "run", "--demo", "--vocabulary", "x.toml"],
     "error: --demo: the demo robot has its own; leave out --vocabulary and --control"),
]  # fmt: skip


@pytest.mark.parametrize(("args", "expected"), MISTAKES, ids=lambda a: str(a)[:40])
def test_a_mistake_is_one_line_naming_the_option(args: list[str], expected: str) -> None:
    code, out, err = ktbt(*args)
    assert (code, out) == (2, "")
    assert err.splitlines() == [expected.format(examples=EXAMPLES)]


def test_a_control_tree_without_a_placeholder_is_refused_saying_how_to_add_one(
    tmp_path: Path,
) -> None:
    door, control = tmp_path / "door.toml", tmp_path / "control.sbt"
    door.write_text(VOCABULARY)
    control.write_text("<sl><c>(DoorClosed)<a>(Push)<e>\n")
    for command in (["peer", "run"], ["fleet", "run", "--out", str(tmp_path / "run")]):
        code, _, err = ktbt(*command, "--vocabulary", str(door), "--control", str(control))
        assert code == 2 and "Traceback" not in err
        [line] = err.splitlines()
        assert line.startswith(f"error: --control {control}: no <k>(...) placeholder")
        assert "add one where learned skills belong, e.g. <sl><k>(new)<e>...<e>" in line
    control.write_text("<sl><k>(new)<e><a>(Fly)<e>\n")
    code, _, err = ktbt("peer", "run", "--vocabulary", str(door), "--control", str(control))
    assert code == 2
    assert err == f"error: --control {control}:1:16: SBT306 unknown action 'Fly'\n"
    assert not (tmp_path / "run").exists()


def test_peer_keys_makes_a_fleets_keys_and_trust_store_and_overwrites_none(
    tmp_path: Path,
) -> None:
    """One command, every robot's key pair and the store naming them (spec/protocol.md
    section 7); the keys load, the store binds each name to its key, and nothing is made
    again over what exists."""
    from ktbt_proto.exchange.signing import Identity
    from ktbt_proto.exchange.trust import TrustStore

    keys = tmp_path / "keys"
    code, _, err = ktbt("peer", "keys", str(keys), "teacher", "robot1")
    assert code == 0, err
    store = TrustStore.load(keys / "trust.txt")
    for name in ("teacher", "robot1"):
        assert store.names[name] == Identity.load(keys / f"{name}.key").public
    assert (keys / "teacher.key").stat().st_mode & 0o077 == 0  # private
    before = (keys / "trust.txt").read_bytes()
    code, _, err = ktbt("peer", "keys", str(keys), "robot2", "teacher")
    assert code == 1 and err == f"error: {keys}: teacher.key exists; keys are never overwritten\n"
    assert not (keys / "robot2.key").exists() and (keys / "trust.txt").read_bytes() == before
    code, _, err = ktbt("peer", "keys", str(tmp_path / "other"), "a b")
    assert code == 2 and "one robot name each" in err and "Traceback" not in err
