"""The language's commands (``ktbt_proto/tools/cli/language.py``: ``fmt``, ``check``, ``show``,
``merge``, ``convert``, ``tour``), run as a user runs them: the real ``ktbt`` process, real
files (spec/stringbt.md sections 6 and 7 for the two forms, 9 for the errors, 12 for
BehaviorTree.CPP).

What tests/tools/test_cli.py shows is not repeated: this module shows ``fmt --check`` over a
folder of clean and dirty files, ``fmt --compact`` in place and its refusal to drop comments,
``fmt --diff`` and an error on stdin; ``check`` over nested folders, of a file that is not UTF-8
and of a folder with no tree (exit 2); ``show`` from stdin and of a missing file; ``merge`` with
its conditions, slot, output file and each of its refusals; ``convert`` of a tree with
placeholders and arguments there and back, and of files it cannot read or write; ``tour`` with
a folder of examples of one's own.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.tools.test_cli import PRETTY, UGLY, ktbt

pytestmark = pytest.mark.network  # every test runs the ktbt command as a process

CONTROL = "<sl><k>(prior)<e><k>(new)<e><a>(Walk)<e>\n"
ROBOT = """<sl>
    <k>(prior)
        <sq>
            <c>(TargetSeen, colour=2)
            <a>(Pick, colour=2, speed=0.5, note="careful")
        <e>
    <e>
    <k>(new)<e>
    <a>(Walk)
<e>
"""


# -- fmt ---------------------------------------------------------------------------------------


def test_fmt_check_over_a_folder_names_what_would_change_and_writes_nothing(
    tmp_path: Path,
) -> None:
    (tmp_path / "sub").mkdir()
    dirty, clean = tmp_path / "dirty.sbt", tmp_path / "sub" / "clean.sbt"
    dirty.write_text(UGLY)
    clean.write_text(PRETTY)
    code, out, err = ktbt("fmt", "--check", str(tmp_path))
    assert (code, out) == (1, "")
    assert err.splitlines() == [
        f"would reformat {dirty}",
        "1 file would be reformatted, 1 file left unchanged.",
    ]
    assert dirty.read_text() == UGLY
    code, _, err = ktbt("fmt", "--check", str(tmp_path / "sub"))
    assert code == 0 and err == "0 files would be reformatted, 1 file left unchanged.\n"


def test_fmt_compact_in_place_writes_one_line_and_refuses_to_drop_comments(
    tmp_path: Path,
) -> None:
    plain, commented = tmp_path / "plain.sbt", tmp_path / "commented.sbt"
    plain.write_text("<sl>\n    <sq> <c>(X) <a>(Y) <e>\n    <a>(Z)\n<e>\n")
    commented.write_text(UGLY)
    code, _, err = ktbt("fmt", "--compact", str(plain), str(commented))
    assert code == 123
    assert plain.read_text() == "<sl><sq><c>(X)<a>(Y)<e><a>(Z)<e>\n"
    assert commented.read_text() == UGLY  # its comment is kept: the file is not rewritten
    assert err.splitlines() == [
        f"reformatted {plain}",
        f"error: cannot format {commented} compact in place: it has comments, which the "
        f"compact form drops (print it instead: ktbt fmt --compact - < {commented})",
        "1 file reformatted, 1 file failed.",
    ]
    code, out, _ = ktbt("fmt", "--compact", "-", stdin=commented.read_bytes())
    assert (code, out) == (0, "<sl><sq><c>(X)<a>(Y)<e><a>(Z)<e>\n")  # printed, as it says


def test_fmt_diff_and_errors_on_stdin() -> None:
    code, out, err = ktbt("fmt", "--diff", "-", stdin=UGLY.encode() + b"\n")
    assert code == 0
    assert out.startswith("--- <stdin>\t(original)\n+++ <stdin>\t(formatted)\n")
    assert err.splitlines() == ["would reformat <stdin>", "1 file would be reformatted."]
    code, out, err = ktbt("fmt", "-", stdin=b"<sq>")
    assert (code, out) == (123, "")
    assert err.splitlines() == [
        "error: cannot format <stdin>:1:5: SBT104 input ends inside <sq> opened at 1:1; "
        "expected <e>",
        "0 files reformatted, 1 file failed.",
    ]


def test_fmt_diff_of_a_file_without_a_final_newline_is_a_well_formed_diff(tmp_path: Path) -> None:
    tree = tmp_path / "t.sbt"
    tree.write_text("<sl><a>(Z)<e>")
    code, out, _ = ktbt("fmt", "--diff", str(tree))
    assert code == 0
    assert "-<sl><a>(Z)<e>\n" in out


# -- check -------------------------------------------------------------------------------------


def test_check_reads_every_tree_below_a_folder_one_line_a_problem(tmp_path: Path) -> None:
    (tmp_path / "a" / "b").mkdir(parents=True)
    good, bad = tmp_path / "a" / "good.sbt", tmp_path / "a" / "b" / "bad.sbt"
    binary = tmp_path / "z.sbt"
    good.write_text(CONTROL)
    bad.write_text("<sl>\n    <neg><e>\n<e>\n")
    binary.write_bytes(b"<a>(X)\xff\n")
    (tmp_path / "notes.txt").write_text("<neg><e>")  # not a tree file: not read
    code, out, err = ktbt("check", str(tmp_path))
    assert code == 1 and err == ""
    assert out.splitlines() == [
        f"{bad}:2:5: SBT301 <neg> needs exactly one child, not 0",
        f"{binary}:1:7: SBT100 byte 0xff at offset 6 is not valid UTF-8",
    ]
    assert ktbt("check", str(good)) == (0, "", "")
    assert ktbt("check", "-", stdin=CONTROL.encode()) == (0, "", "")


def test_check_of_a_folder_with_no_tree_is_a_usage_error(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("not a tree")
    code, out, err = ktbt("check", str(tmp_path))
    assert (code, out) == (2, "")
    assert err == f"error: no .sbt file in {tmp_path}\n"


# -- show --------------------------------------------------------------------------------------


def test_show_draws_stdin_as_an_outline_and_names_a_missing_file(tmp_path: Path) -> None:
    code, out, _ = ktbt("show", "-", stdin=b"<sl><sq><c>(X)<a>(Y, n=2)<e><k>(new)<e><e>")
    assert code == 0
    assert out.splitlines() == [
        "Selector",
        "├── Sequence",
        "│   ├── Condition X",
        "│   └── Action Y(n=2)",
        "└── Knowledge [new] (empty)",
    ]
    missing = tmp_path / "nope.sbt"
    code, out, err = ktbt("show", str(missing))
    assert (code, out) == (1, "")
    assert err == f"error: cannot read {missing}: No such file or directory\n"


# -- merge -------------------------------------------------------------------------------------


def test_merge_puts_the_item_under_its_conditions_into_the_slot(tmp_path: Path) -> None:
    control, skill = tmp_path / "control.sbt", tmp_path / "skill.sbt"
    control.write_text(CONTROL)
    skill.write_text("<a>(Pick, colour=2)\n")
    code, out, _ = ktbt(
        "merge", str(control), str(skill), "--when", "TargetSeen(colour=2), !Carrying"
    )
    assert code == 0
    assert out == (
        "<sl>\n    <k>(prior)<e>\n    <k>(new)\n        <sq>\n"
        "            <c>(TargetSeen, colour=2)\n            <c>(!Carrying)\n"
        "            <a>(Pick, colour=2)\n        <e>\n    <e>\n    <a>(Walk)\n<e>\n"
    )
    code, out, _ = ktbt("merge", str(control), "-", "--slot", "prior", "--compact",
                        stdin=b"<a>(Pick)")  # fmt: skip
    assert (code, out) == (0, "<sl><k>(prior)<a>(Pick)<e><k>(new)<e><a>(Walk)<e>\n")
    merged = tmp_path / "merged.sbt"
    code, out, _ = ktbt("merge", str(control), str(skill), "--when", "A", "--compact",
                        "-o", str(merged))  # fmt: skip
    assert (code, out) == (0, "")
    expected = "<sl><k>(prior)<e><k>(new)<sq><c>(A)<a>(Pick,colour=2)<e><e><a>(Walk)<e>\n"
    assert merged.read_text() == expected
    assert control.read_text() == CONTROL  # the control tree itself is never rewritten


def test_merge_refusals_are_one_line_and_write_nothing(tmp_path: Path) -> None:
    control, skill = tmp_path / "control.sbt", tmp_path / "skill.sbt"
    control.write_text(CONTROL)
    skill.write_text("<a>(Pick)\n")
    code, out, err = ktbt("merge", str(control), str(skill), "--slot", "nope")
    assert (code, out) == (1, "")
    assert err == "error: cannot merge 1:1: SBT401 the tree has no placeholder <k>(nope)\n"
    nowhere = tmp_path / "missing" / "out.sbt"
    code, out, err = ktbt("merge", str(control), str(skill), "-o", str(nowhere))
    assert (code, out) == (1, "")
    assert err == f"error: cannot write {nowhere}: No such file or directory\n"
    assert not nowhere.parent.exists()
    code, _, err = ktbt("merge", "-", "-", stdin=b"<a>(X)")
    assert code == 2 and err == "error: only one of CONTROL and SUBTREE can be '-'\n"


# -- convert -----------------------------------------------------------------------------------


def test_convert_keeps_placeholders_and_arguments_there_and_back(tmp_path: Path) -> None:
    source, xml, back = tmp_path / "robot.sbt", tmp_path / "robot.xml", tmp_path / "back.sbt"
    source.write_text(ROBOT)
    assert ktbt("convert", str(source), str(xml)) == (0, "", "")
    text = xml.read_text()
    assert '<ReactiveFallback name="k:prior">' in text and '<ReactiveFallback name="k:new">' in text
    assert '<Pick colour="2" speed="0.5" note="careful"/>' in text
    assert ktbt("convert", str(xml), str(back)) == (0, "", "")
    assert back.read_text() == ROBOT


def test_convert_names_the_file_it_cannot_read_or_write(tmp_path: Path) -> None:
    source = tmp_path / "robot.sbt"
    source.write_text(ROBOT)
    missing, nowhere = tmp_path / "missing.sbt", tmp_path / "no" / "robot.xml"
    code, _, err = ktbt("convert", str(missing), str(tmp_path / "x.xml"))
    assert code == 1
    assert err == (
        f"error: cannot convert {missing}: cannot read {missing}: No such file or directory\n"
    )
    code, _, err = ktbt("convert", str(source), str(nowhere))
    assert code == 1
    assert err == (
        f"error: cannot convert {source}: cannot write {nowhere}: No such file or directory\n"
    )
    code, _, err = ktbt("convert", str(source), str(tmp_path / "robot.txt"))
    assert code == 1
    assert err == (
        f"error: cannot convert {source}: convert .sbt to .xml or .xml to .sbt, "
        "not '.sbt' to '.txt'\n"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.sbt"]


# -- tour --------------------------------------------------------------------------------------


def test_tour_reads_the_examples_folder_it_is_given(tmp_path: Path) -> None:
    (tmp_path / "paper_control.sbt").write_text("<sl>\n    <a>(Hello)\n<e>\n")
    (tmp_path / "sar_vocabulary.toml").write_text('conditions = ["TargetSeen"]\nactions = []\n')
    code, out, _ = ktbt("tour", "--examples", str(tmp_path))
    assert code == 0
    lines = out.splitlines()
    assert "<sl><a>(Hello)<e>" in lines  # its own tree, on the wire
    # Its own vocabulary: this one has no actions, so the tour's skill is refused twice over.
    assert "knowledge.sbt:1:30: SBT306 unknown action 'PickTreasure'" in lines
    assert "knowledge.sbt:1:47: SBT306 unknown action 'Teleport'" in lines
    (tmp_path / "sar_vocabulary.toml").unlink()
    code, out, err = ktbt("tour", "--examples", str(tmp_path))
    assert (code, out) == (1, "")
    assert err == f"error: --examples: {tmp_path / 'sar_vocabulary.toml'} not found\n"


def test_check_takes_the_vocabulary_the_project_names_as_the_language_server_does(
    tmp_path: Path,
) -> None:
    """Without --vocabulary, a file is checked against its project's (``[tool.ktbt]`` in the
    nearest pyproject.toml above it, spec/stringbt.md section 5.1); --vocabulary wins; a
    project whose vocabulary cannot be read is one line naming its settings, exit 2."""
    from ktbt_proto.files import packaged

    (tmp_path / "robot.toml").write_bytes(packaged("examples", "sar_vocabulary.toml").read_bytes())
    (tmp_path / "pyproject.toml").write_text('[tool.ktbt]\nvocabulary = "robot.toml"\n')
    trees = tmp_path / "trees"
    trees.mkdir()
    (trees / "t.sbt").write_text("<sq><c>(TargetSeen, colour=2)<a>(Teleport)<e>\n")
    code, out, _ = ktbt("check", str(trees), cwd=tmp_path.parent)
    assert code == 1 and out == f"{trees / 't.sbt'}:1:30: SBT306 unknown action 'Teleport'\n"
    (tmp_path / "other.toml").write_text('conditions = ["TargetSeen"]\nactions = ["Teleport"]\n')
    code, out, _ = ktbt("check", "--vocabulary", str(tmp_path / "other.toml"), str(trees))
    assert code == 0, out
    (tmp_path / "pyproject.toml").write_text('[tool.ktbt]\nvocabulary = "missing.toml"\n')
    code, out, err = ktbt("check", str(trees))
    assert code == 2 and out == "" and len(err.splitlines()) == 1
    assert err.startswith(f"error: {tmp_path / 'pyproject.toml'} [tool.ktbt]: vocabulary:")
