"""The instruction parser reads one edit or refuses with the reason, never guesses."""

import pytest

from gae_jax import instructions


@pytest.mark.parametrize("prompt, region, colour", [
    ("Turn the lips blue", "lips", "blue"), ("make the hair white", "hair", "white"),
    ("give her red eyes", "iris", "red"), ("paint the face green", "skin", "green")])
def test_one_region_and_one_colour_is_read(prompt, region, colour):
    ins = instructions.parse(prompt)
    assert ins == instructions.Instruction(region, instructions.COLOURS[colour], False)


def test_stripes_are_a_pattern_of_the_colour():
    ins = instructions.parse("add green stripes to the skin")
    assert ins.stripes and ins.region == "skin"


@pytest.mark.parametrize("prompt, reason", [
    ("turn the lips blue and the hair white", "names 2 regions (lips, hair)"),
    ("turn the blue lips red", "names 2 colours (blue, red)"),
    ("don't make the lips red", "negated"),
    ("make the lips not red", "negated"),
    ("make him look older", "names no region and no colour it knows"),
    ("turn the lips sideways", "names no colour it knows"),
    ("make it an oil painting", "use --editor style")])
def test_ambiguous_or_unknown_prompts_are_refused_with_the_reason(prompt, reason):
    with pytest.raises(ValueError, match="does not understand") as e:
        instructions.parse(prompt)
    assert reason in str(e.value) and "It understands regions:" in str(e.value)


def test_styles_match_whole_words():
    assert instructions.parse_style("Make it an oil painting") == "oil"
    assert instructions.parse_style("a pencil sketch") == "sketch"
    for prompt in ("spoil it", "turn the lips blue", "toilet"):
        with pytest.raises(ValueError, match="style editor does not understand"):
            instructions.parse_style(prompt)


def test_captions_name_the_edit():
    assert instructions.captions("turn the lips blue")[1].endswith("with blue lips")
    assert "oil painting" in instructions.captions("make it an oil painting")[1]
