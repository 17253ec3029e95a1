"""The instruction parser reads one edit or refuses with the reason, never guesses or drops a
word."""

import matplotlib.colors as mcolors
import numpy as np
import pytest

from gae_jax import colours, instructions
from gae_jax.model import head


@pytest.mark.parametrize("prompt, region, colour", [
    ("Turn the lips blue", "lips", "blue"), ("make the hair white", "hair", "white"),
    ("give her red eyes", "iris", "red"), ("paint the face green", "skin", "green")])
def test_one_region_and_one_colour_is_read(prompt, region, colour):
    ins = instructions.parse(prompt)
    assert ins == instructions.Instruction(region, instructions.COLOURS[colour], False)


@pytest.mark.parametrize("prompt, region", [
    ("make her lipstick red", "lips"), ("paint the mouth black", "lips"),
    ("make the complexion green", "skin"), ("make the whites of the eyes yellow", "sclera"),
    ("turn his eye whites pink", "sclera"), ("make the inside of the mouth black", "mouth"),
    ("make the pupils white", "pupil"), ("make her eye colour green", "iris"),
    ("make the tooth gold", "teeth"), ("dye the brows black", "brows")])
def test_region_synonyms_name_the_region(prompt, region):
    assert instructions.parse(prompt).region == region


@pytest.mark.parametrize("prompt, name", [
    ("turn the lips navy blue", "navy blue"), ("make the lips teal", "teal"),
    ("make the lips crimson", "crimson"), ("turn the lips lipstick red", "lipstick red"),
    ("make the hair auburn", "auburn"), ("make the lips cornflowerblue", "cornflowerblue")])
def test_colour_names_come_from_the_xkcd_and_css4_tables(prompt, name):
    ins = instructions.parse(prompt)
    expected = mcolors.to_rgb(mcolors.XKCD_COLORS.get("xkcd:" + name)
                              or mcolors.CSS4_COLORS[name])
    np.testing.assert_allclose(ins.colour, expected)
    assert ins.colour_name == name


def test_every_table_name_is_read_back_as_itself():
    """Each of the ~1,000 names, in a prompt, gives its own RGB (three names are also
    modifiers or spellings, read as such)."""
    read_otherwise = {"gray": "grey", "dark": "dark", "pale": "pale"}
    for name, rgb in colours.table().items():
        ins = instructions.parse(f"turn the lips {name}")
        assert ins.colour_name == read_otherwise.get(name, name)
        if name not in read_otherwise:
            np.testing.assert_allclose(ins.colour, rgb)


def test_hair_colours_that_no_table_has():
    assert instructions.parse("make the hair blonde").colour == colours.HAIR["blonde"]
    assert instructions.parse("make the hair strawberry blonde").colour_name == \
        "strawberry blonde"


def test_a_modifier_shifts_the_colour_that_follows_or_the_regions_own():
    lighter = instructions.parse("make the lips light crimson")
    crimson = np.asarray(mcolors.to_rgb(mcolors.XKCD_COLORS["xkcd:crimson"]))
    np.testing.assert_allclose(lighter.colour, crimson + 0.5 * (1 - crimson))
    # "light blue" is a name of its own (XKCD's), not blue lightened
    np.testing.assert_allclose(instructions.parse("make the lips light blue").colour,
                               mcolors.to_rgb(mcolors.XKCD_COLORS["xkcd:light blue"]))
    pale = instructions.parse("make the skin pale")
    assert pale.region == "skin" and pale.colour == colours.modify(head.ALBEDO["skin"], "pale")
    darker = instructions.parse("make the hair darker").colour
    np.testing.assert_allclose(darker, 0.55 * np.asarray(head.ALBEDO["hair"]))


@pytest.mark.parametrize("modifier", sorted(colours.MODIFIERS))
def test_modifiers_keep_a_colour_a_colour_and_move_it_their_way(modifier):
    luma = colours.LUMA
    for rgb in [(0.12, 0.28, 0.85), (0.87, 0.68, 0.56), (0.05, 0.05, 0.05), (1.0, 1.0, 0.0)]:
        out = np.asarray(colours.modify(rgb, modifier))
        assert np.all((out >= 0) & (out <= 1))
        kind = colours.MODIFIERS[modifier]
        if kind in ("light", "pale"):
            assert out @ luma >= np.asarray(rgb) @ luma - 1e-9
        if kind == "dark":
            assert out @ luma < np.asarray(rgb) @ luma


def test_stripes_are_a_pattern_of_the_colour():
    ins = instructions.parse("add green stripes to the skin")
    assert ins.stripes and ins.region == "skin"


@pytest.mark.parametrize("prompt, reason", [
    ("turn the lips blue and the hair white", "names 2 regions (lips, hair)"),
    ("turn the blue lips red", "names 2 colours (blue, red)"),
    ("don't make the lips red", "negated"),
    ("make the lips not red", "negated"),
    ("make him look older", "'older', a change of expression, age or identity"),
    ("turn the lips sideways", "does not know the word 'sideways'"),
    ("make the eyebrows white and thick", "'thick', a change of shape or size"),
    ("give him a black beard", "'beard', something this head does not have"),
    ("paint the nose red", "'nose' is not a region of its own"),
    ("add red spots to the skin", "'spots', a pattern other than stripes"),
    ("make the lips 50% blue", "does not know the word '50%'"),
    ("make the lips", "names no colour it knows"),
    ("make it an oil painting", "use --editor style")])
def test_what_the_editor_cannot_do_is_refused_with_the_reason(prompt, reason):
    with pytest.raises(ValueError, match="does not understand") as e:
        instructions.parse(prompt)
    assert reason in str(e.value) and "It understands regions:" in str(e.value)


def test_every_accepted_instruction_has_an_ideal_edit_of_its_region():
    model_faces = np.array([[0, 1, 2], [2, 1, 3], [3, 4, 2]])
    face_regions = np.array([head.REGION_ID["lips"], head.REGION_ID["lips"],
                             head.REGION_ID["skin"]])
    albedo = np.full((5, 3), 0.5)
    rest = np.zeros((5, 3))
    ins = instructions.parse("turn the lips navy blue")
    ideal = instructions.ideal_albedo(ins, albedo, model_faces, face_regions, rest)
    lips = instructions.region_vertices(model_faces, face_regions, "lips", 5)
    np.testing.assert_allclose(ideal[lips], np.tile(ins.colour, (lips.sum(), 1)))
    np.testing.assert_array_equal(ideal[~lips], albedo[~lips])


def test_styles_match_whole_words():
    assert instructions.parse_style("Make it an oil painting") == "oil"
    assert instructions.parse_style("a pencil sketch") == "sketch"
    for prompt in ("spoil it", "turn the lips blue", "toilet"):
        with pytest.raises(ValueError, match="style editor does not understand"):
            instructions.parse_style(prompt)


def test_captions_name_the_edit_as_said():
    assert instructions.captions("turn the lips blue")[1].endswith("with blue lips")
    assert instructions.captions("turn the lips navy blue")[1].endswith("with navy blue lips")
    assert instructions.captions("give her red eyes")[1].endswith("with red eyes")
    assert "oil painting" in instructions.captions("make it an oil painting")[1]
