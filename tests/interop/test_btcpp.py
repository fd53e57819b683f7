"""BehaviorTree.CPP v4 XML: exact export, lossless round trips, and positioned import errors."""

from __future__ import annotations

import dataclasses
import itertools
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import ktbt_proto as kp
from ktbt_proto.errors import ErrorCode
from ktbt_proto.formatter import format_tree
from ktbt_proto.interop import convert, from_xml, to_xml
from ktbt_proto.interop.btcpp import decode_value, encode_value, reference
from ktbt_proto.tree import Container, Node, Parallel, Placeholder
from tests.strategies import trees, values

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
HEAD = '<?xml version="1.0" encoding="UTF-8"?>\n<root BTCPP_format="4">\n<BehaviorTree ID="T">\n'
TAIL = "\n</BehaviorTree>\n</root>\n"


def doc(body: str) -> str:
    """A document whose tree starts on line 4 of the text."""
    return HEAD + body + TAIL


def error(text: str | bytes) -> kp.StringBTError:
    with pytest.raises(kp.StringBTError) as info:
        from_xml(text)
    return info.value


@pytest.mark.parametrize("name", ["sar_control.sbt", "paper_control.sbt", "teach_learn.sbt"])
def test_examples_round_trip(name: str) -> None:
    tree = kp.parse((EXAMPLES / name).read_text())
    xml = to_xml(tree)
    assert from_xml(xml) == tree
    assert to_xml(from_xml(xml)) == xml


def test_sar_control_xml_is_the_export() -> None:
    tree = kp.parse((EXAMPLES / "sar_control.sbt").read_text())
    assert (EXAMPLES / "sar_control.xml").read_text() == to_xml(tree)


SMALL = """\
<msq>
    <c>(!nav.Near, d=1.5, frame="map", ok=true)
    <pl>(1)
        <tt1>(3)
            <a>(Say, text="42")
        <e>
        <tt2>(2)
            <w>(4)
        <e>
    <e>
    <k>(new)<e>
    <wt>(2.0)
    <wt>(0.25)
<e>
"""

SMALL_XML = """\
<?xml version="1.0" encoding="UTF-8"?>
<root BTCPP_format="4" main_tree_to_execute="MainTree">
  <BehaviorTree ID="MainTree">
    <Sequence>
      <Inverter name="!nav.Near">
        <nav-Near d="1.5" frame="map" ok="true"/>
      </Inverter>
      <Parallel success_count="1" failure_count="2">
        <KTBT_TT1 ticks="3">
          <Say text="&quot;42&quot;"/>
        </KTBT_TT1>
        <KTBT_TT2 ticks="2">
          <KTBT_WaitTicks ticks="4"/>
        </KTBT_TT2>
      </Parallel>
      <ReactiveFallback name="k:new">
        <AlwaysFailure/>
      </ReactiveFallback>
      <Sleep name="wt:2.0" msec="2000"/>
      <Sleep msec="250"/>
    </Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <Action ID="KTBT_WaitTicks">
      <input_port name="ticks" type="unsigned int">stringBT &lt;w&gt;: RUNNING for this many \
ticks, then SUCCESS</input_port>
    </Action>
    <Action ID="Say">
      <input_port name="text" type="std::string"/>
    </Action>
    <Condition ID="nav-Near">
      <input_port name="d" type="double"/>
      <input_port name="frame" type="std::string"/>
      <input_port name="ok" type="bool"/>
    </Condition>
    <Decorator ID="KTBT_TT1">
      <input_port name="ticks" type="unsigned int">stringBT &lt;tt1&gt;: RUNNING for this many \
ticks, then the child's status</input_port>
    </Decorator>
    <Decorator ID="KTBT_TT2">
      <input_port name="ticks" type="unsigned int">stringBT &lt;tt2&gt;: the child's status for \
this many ticks, then FAILURE</input_port>
    </Decorator>
  </TreeNodesModel>
</root>
"""


def test_exact_xml_of_a_small_tree() -> None:
    tree = kp.parse(SMALL)
    assert to_xml(tree) == SMALL_XML
    assert from_xml(SMALL_XML) == tree


def test_explicit_form_is_read() -> None:
    # BT.CPP 3's and older exports' form: <Action ID="X"/>, <Decorator ID="KTBT_TT1">.
    xml = """<root BTCPP_format="4"><BehaviorTree ID="Main"><Sequence>
        <Condition ID="Seen" colour="2"/><Decorator ID="KTBT_TT2" ticks="4">
        <Action ID="KTBT_WaitTicks" ticks="1"/></Decorator><Action ID="Go"/></Sequence>
        </BehaviorTree></root>"""
    tree = from_xml(xml)
    assert kp.format_tree(tree, "compact") == "<msq><c>(Seen,colour=2)<tt2>(4)<w>(1)<e><a>(Go)<e>"


def test_groot2_compact_form_is_read() -> None:
    # Groot2 saves nodes as <ID .../> and declares them in the model.
    xml = """<root BTCPP_format="4"><BehaviorTree ID="Main"><ReactiveSequence>
        <Seen colour="2"/><Go/><KTBT_TT1 ticks="1"><Go/></KTBT_TT1></ReactiveSequence>
        </BehaviorTree><TreeNodesModel><Condition ID="Seen"/><Action ID="Go"/></TreeNodesModel>
        </root>"""
    tree = from_xml(xml)
    assert kp.format_tree(tree, "compact") == "<sq><c>(Seen,colour=2)<a>(Go)<tt1>(1)<a>(Go)<e><e>"


def test_parallel_counts() -> None:
    three = "<Action ID='A'/><Action ID='B'/><Action ID='C'/>"
    cases = {
        "": None,
        'success_count="-1"': None,
        'success_count="3" failure_count="1"': 3,
        'success_count="2" failure_count="2"': 2,
        'success_count="-2" failure_count="2"': 2,
        'success_count="1" failure_count="-1"': 1,
    }
    for attrs, threshold in cases.items():
        node = from_xml(doc(f"<Parallel {attrs}>{three}</Parallel>")).root
        assert isinstance(node, Parallel) and node.threshold == threshold
    err = error(doc(f'<Parallel success_count="2" failure_count="1">{three}</Parallel>'))
    assert (err.code, err.line, err.column) == (ErrorCode.INVALID_THRESHOLD, 4, 1)


def unique_placeholders(node: Node) -> Node:
    counter = itertools.count()

    def go(n: Node) -> Node:
        if isinstance(n, Container):
            n = dataclasses.replace(n, children=tuple(go(c) for c in n.children))
            if isinstance(n, Placeholder):
                n = dataclasses.replace(n, name=f"k{next(counter)}")
        return n

    return go(node)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(trees(valid=True))
def test_random_trees_round_trip(root: Node) -> None:
    tree = kp.Tree(unique_placeholders(root))
    try:
        xml = to_xml(tree)
    except kp.ValidationError as err:  # a name or a subnormal BT.CPP cannot load: refused
        assert err.code in (ErrorCode.INVALID_NAME, ErrorCode.INVALID_VALUE), err
        assume(False)
    assert from_xml(xml) == tree
    assert from_xml(xml.encode()) == tree


@given(values)
def test_values_keep_their_type(value: bool | int | float | str) -> None:
    decoded = decode_value(encode_value(value))
    assert type(decoded) is type(value) and repr(decoded) == repr(value)


def test_values_are_quoted_only_when_needed() -> None:
    plain = ["map", "", "{goal", "a {goal}", "1 m", "True"]
    assert [encode_value(v) for v in plain] == plain
    quoted = ["1", "-2.5e3", "true", '"x', "\x01", " {goal}", " {a b} ", "{}", "{=}"]
    assert [encode_value(v) for v in quoted] == [
        '"1"', '"-2.5e3"', '"true"', '"\\"x"', '"\\u0001"', '" {goal}"', '" {a b} "', '"{}"',
        '"{=}"',
    ]  # fmt: skip
    # Braced but no reference: quoted, so a peer's string stays a string in BT.CPP.
    assert from_xml(to_xml(kp.parse('<a>(Go, s="{x }")'))) == kp.parse('<a>(Go, s="{x }")')


# Exactly a key between braces, the key a BT.CPP port name: a blackboard reference (spec
# section 12). Anything else braced is a string, quoted.
REFERENCES = {"{goal}": "goal", "{path}": "path", "{map_frame2}": "map_frame2", "{X}": "X"}
NOT_REFERENCES = ["{_x}", "{2x}", "{name}", "{ID}", "{a.b}", "{a-b}", "{ goal}", "{goal }",
                  "{goal} ", "{}", "{{x}}", "{=}", "{\u00e9}", "{goal}\n", "goal"]  # fmt: skip


def test_a_braced_key_is_exported_as_a_blackboard_reference() -> None:
    for text, key in REFERENCES.items():
        assert reference(text) == key and encode_value(text) == text
    for text in NOT_REFERENCES:
        assert reference(text) is None, text
        braced = text.strip(" ")  # what BT.CPP would read as a reference: quoted
        if braced.startswith("{") and braced.endswith("}"):
            assert encode_value(text) == json.dumps(text, ensure_ascii=False), text
        else:
            assert decode_value(encode_value(text)) == text
    assert reference(3) is None and reference(True) is None


def test_references_round_trip_and_are_the_subtree_ports() -> None:
    text = (
        '<sq><c>(DoorClosed, side="{side}")<a>(ComputePath, goal="{goal}", path="{path}")'
        '<a>(FollowPath, path="{path}", speed=0.5)<a>(Say, text="{goal")<e>'
    )
    tree = kp.parse(text)
    xml = to_xml(tree, tree_id="OpenDoor")
    assert '<ComputePath goal="{goal}" path="{path}"/>' in xml
    assert '<Say text="{goal"/>' in xml  # not a reference: a string as it is
    assert from_xml(xml) == tree
    assert format_tree(from_xml(xml), "compact") == format_tree(tree, "compact")
    doc = ET.fromstring(xml.encode())
    model = {el.get("ID"): el for el in doc.iterfind("TreeNodesModel/*")}
    # The subtree's ports: every key its arguments refer to, for a tree including it to wire.
    subtree = model["OpenDoor"]
    assert subtree.tag == "SubTree"
    assert [(p.tag, p.get("name")) for p in subtree] == [
        ("inout_port", "goal"), ("inout_port", "path"), ("inout_port", "side")
    ]  # fmt: skip
    # A port given only references is untyped: its type is the blackboard entry's.
    ports = {p.get("name"): p.get("type") for p in model["FollowPath"]}
    assert ports == {"path": None, "speed": "double"}
    assert {p.get("name"): p.get("type") for p in model["DoorClosed"]} == {"side": None}
    # No reference, no <SubTree> model.
    assert "<SubTree" not in to_xml(kp.parse('<a>(Go, s="{x }")'))
    numbers = [encode_value(v) for v in (1, 1.0, 1e16, -0.0, True)]
    assert numbers == ["1", "1.0", "1e+16", "-0.0", "true"]


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("<a>(Go, _skipIf=1)", "argument '_skipIf'"),
        ("<a>(Go, name=1)", "argument 'name'"),
        ("<a>(Sleep)", "built-in"),
        ("<c>(KTBT_TT1)", "reserved"),
        ("<a>(Action)", "built-in"),
        ("<c>(Condition)", "built-in"),
        ("<a>(SubTree)", "built-in"),
        ("<a>(root)", "built-in"),
        ("<sq><c>(X)<a>(X)<e>", "both a condition and an action"),
    ],
)
def test_names_bt_cpp_cannot_load_are_refused(text: str, reason: str) -> None:
    with pytest.raises(kp.ValidationError, match=reason) as info:
        to_xml(kp.parse(text))
    assert info.value.code is ErrorCode.INVALID_NAME


@pytest.mark.parametrize(
    ("text", "limit"),
    [
        ("<w>(4294967296)", ("4294967295", 'ticks="4294967295"')),
        ("<tt1>(4294967296)<a>(A)<e>", ("4294967295", 'ticks="4294967295"')),
        ("<wt>(4294968)", ("4294967.295", 'msec="4294967295"')),
    ],
)
def test_tick_counts_beyond_an_unsigned_int_are_refused(text: str, limit: tuple[str, str]) -> None:
    largest, attribute = limit
    assert attribute in to_xml(kp.parse(re.sub(r"\(\d+\)", f"({largest})", text, count=1)))
    with pytest.raises(kp.ValidationError, match="unsigned int") as info:
        to_xml(kp.parse(text))
    assert info.value.code is ErrorCode.INVALID_DURATION


@pytest.mark.parametrize(
    "body",
    [
        '<KTBT_TT1 ticks="4294967296"><Action ID="A"/></KTBT_TT1>',
        '<Action ID="KTBT_WaitTicks" ticks="4294967296"/>',
        '<Sleep msec="4294967296"/>',
    ],
)
def test_import_refuses_counts_btcpp_cannot_load(body: str) -> None:
    assert from_xml(doc(body.replace("4294967296", "4294967295")))
    err = error(doc(body))
    assert err.code is ErrorCode.INVALID_DURATION and "unsigned int" in err.message


@pytest.mark.parametrize("value", [5e-324, -1e-310, 2.225073858507201e-308])
def test_subnormal_doubles_are_refused(value: float) -> None:
    smallest_normal = kp.Tree(kp.Action("Go", (("v", 2.2250738585072014e-308),)))
    assert from_xml(to_xml(smallest_normal)) == smallest_normal
    with pytest.raises(kp.ValidationError, match="subnormal") as info:
        to_xml(kp.Tree(kp.Action("Go", (("v", value),))))
    assert info.value.code is ErrorCode.INVALID_VALUE


def test_the_tree_id_is_escaped() -> None:
    xml = to_xml(kp.parse("<a>(Go)"), tree_id='a"b')
    assert 'main_tree_to_execute="a&quot;b"' in xml and from_xml(xml) == kp.parse("<a>(Go)")


@pytest.mark.parametrize(
    ("body", "code", "column", "words"),
    [
        ('<Repeat num_cycles="3"><Action ID="A"/></Repeat>', "SBT102", 1, "<Repeat>"),
        ('<SequenceWithMemory><Action ID="A"/></SequenceWithMemory>', "SBT102", 1, "failed"),
        ('<Sequence>  <SubTree ID="S"/></Sequence>', "SBT102", 13, "<SubTree>"),
        ('<Sequence><Control ID="IfThenElse"/></Sequence>', "SBT102", 11, "IfThenElse"),
        ("<Sequence><Unknown/></Sequence>", "SBT102", 11, "TreeNodesModel"),
        ("<Sequence><AlwaysFailure/></Sequence>", "SBT102", 11, "placeholder"),
        ('<Sequence><Action ID="A" _skipIf="x"/></Sequence>', "SBT103", 11, "'_skipIf'"),
        ('<Sequence><Action ID="KTBT_Foo"/></Sequence>', "SBT102", 11, "KTBT_Foo"),
        ('<Sequence><Action ID="A"><Action ID="B"/></Action></Sequence>', "SBT103", 26, "child"),
        ('<Inverter><Action ID="A"/><Action ID="B"/></Inverter>', "SBT301", 1, "one child"),
        ("<Sequence/>", "SBT302", 1, "needs a child"),
        ('<Decorator ID="KTBT_TT1" ticks="1.5"><Action ID="A"/></Decorator>', "SBT307", 1, "ticks"),
        ('<Action ID="KTBT_WaitTicks" ticks="-1"/>', "SBT307", 1, "number of ticks"),
        ('<Sleep msec="x"/>', "SBT307", 1, "msec"),
        ('<Condition ID="Sleep" msec="1"/>', "SBT102", 1, "Sleep is BT.CPP's own Action"),
        ('<Action ID="Sequence"/>', "SBT102", 1, "Sequence is BT.CPP's own Control"),
        ('<Action ID="1x"/>', "SBT303", 1, "'1x'"),
        ('<Inverter foo="1"><Action ID="A"/></Inverter>', "SBT103", 1, "'foo'"),
    ],
)
def test_unsupported_elements_are_located(body: str, code: str, column: int, words: str) -> None:
    err = error(doc(body))
    assert (err.code.value, err.line, err.column) == (code, 4, column), str(err)
    assert words in err.message


def test_document_level_errors() -> None:
    assert error("").code is ErrorCode.EMPTY
    assert error("<tree/>").message.startswith("<tree> is not supported")
    assert error('<root BTCPP_format="3"/>').code is ErrorCode.UNEXPECTED_TOKEN
    assert error("<root/>").code is ErrorCode.EMPTY
    assert error('<root main_tree_to_execute="X"><BehaviorTree ID="Y"/></root>').line == 1
    err = error(HEAD + '<Action ID="A"/>\n  <Action ID="B"/>' + TAIL)
    assert (err.code, err.line, err.column) == (ErrorCode.EXTRA_ROOT, 5, 3)
    err = error('<root>\n<include path="x.xml"/></root>')
    assert (err.code, err.line, err.column) == (ErrorCode.UNKNOWN_TAG, 2, 1)


def test_malformed_xml_is_located() -> None:
    err = error(doc('<Sequence>\n  <Action ID="A">\n</Sequence>'))
    assert (err.code, err.line, err.column) == (ErrorCode.UNEXPECTED_TOKEN, 6, 3)
    assert "malformed XML: mismatched tag" in err.message and "^" in str(err)
    # Columns count characters, not UTF-8 bytes.
    err = error(doc('<Action ID="é" x="ü"/> <'))
    assert (err.line, err.column) == (4, 25)
    err = error(doc('<Action ID="é" x="ü" x="1"/>'))
    assert (err.line, err.column) == (4, 22)
    assert error(b"<root>\xff</root>").code is ErrorCode.INVALID_UTF8
    assert error("<root>\ud800</root>").code is ErrorCode.INVALID_UTF8


def test_doctype_and_entities_are_refused() -> None:
    laughs = '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">]>\n<root>&a;</root>'
    err = error(laughs)
    assert (err.code, err.line) == (ErrorCode.UNEXPECTED_TOKEN, 2) and "DOCTYPE" in err.message
    assert "undefined entity" in error(doc('<Action ID="&ext;"/>')).message


def test_limits_apply() -> None:
    deep = "<Inverter>" * 200 + '<Action ID="A"/>' + "</Inverter>" * 200
    assert error(doc(deep)).code is ErrorCode.TOO_DEEP
    assert error(doc(f'<Action ID="A" x="{"1" * 5000}"/>')).code is ErrorCode.LITERAL_TOO_LONG


_SOUP_WORDS = (
    "< > /> </ = \" ' &amp; &#10; <!--c--> <![CDATA[x]]> <?pi?> root BehaviorTree Sequence "
    "Inverter Parallel Action Condition Sleep KTBT_TT1 ID= name= ticks= msec= success_count= "
    '"k:x" "!A" "A" "-1" "2" é'
)
XML_SOUP = [*_SOUP_WORDS.split(" "), " ", " ", "\n"]


@st.composite
def mutated(draw: st.DrawFn) -> str:
    """The valid SMALL_XML with a few characters overwritten somewhere."""
    at = draw(st.integers(0, len(SMALL_XML)))
    patch = draw(st.text(max_size=3))
    return SMALL_XML[:at] + patch + SMALL_XML[at + len(patch) :]


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(
        st.text(max_size=60),
        st.binary(max_size=60),
        st.lists(st.sampled_from(XML_SOUP), max_size=40).map("".join),
        mutated(),
    )
)
def test_garbage_raises_only_stringbt_errors(text: str | bytes) -> None:
    try:
        from_xml(text)
    except kp.StringBTError as err:
        assert err.line >= 1 and err.column >= 1


def test_convert_both_ways(tmp_path: Path) -> None:
    xml, sbt = tmp_path / "t.xml", tmp_path / "t.sbt"
    convert(EXAMPLES / "sar_control.sbt", xml)
    assert xml.read_text() == (EXAMPLES / "sar_control.xml").read_text()
    convert(xml, sbt)
    tree = kp.parse(sbt.read_text())
    assert tree == kp.parse((EXAMPLES / "sar_control.sbt").read_text())
    assert sbt.read_text() == kp.format_tree(tree)
    with pytest.raises(ValueError, match=r"'\.sbt' to '\.sbt'"):
        convert(sbt, tmp_path / "u.sbt")
