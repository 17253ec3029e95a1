"""The WABE study's rows and its claim arithmetic (gae_jax/run/wabe_scenario.py)."""

from gae_jax.run import wabe_scenario
from gae_jax.edit.config import EditConfig
from gae_jax.evaluation import protocols


def record(teeth: float) -> dict:
    return {"evaluation": {p: {"ours": {"psnr": {"teeth": teeth + i},
                                        "change": {"teeth": teeth + i, "tongue": 20.0}}}
                           for i, p in enumerate(protocols.PROTOCOLS)}}


def test_claim_gain_is_paired_per_seed_and_set_against_the_larger_seed_range():
    # Teeth per seed (protocol means 1 dB above the first protocol's value).
    standard, wabe_grad = (10.0, 11.0, 9.5), (15.0, 16.5, 15.0)
    results = {}
    for method, values in (("standard", standard), ("wabe_grad", wabe_grad)):
        for name, v in zip(wabe_scenario.seed_rows(method, "adam"), values):
            results[name] = record(v - 1.0)
    lines = wabe_scenario.claim_lines(results)  # the 200-iteration and SGD rows are missing
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines
            if line.startswith("| adam")]
    assert [r[1] for r in rows] == ["teeth vs ideal", "teeth change", "tongue change"]
    cells = rows[0]
    assert cells[0] == "adam, 100 it."
    assert cells[2] == "10.00 / 11.00 / 9.50" and cells[3] == "15.00 / 16.50 / 15.00"
    assert cells[4] == "+5.00 / +5.50 / +5.50"
    assert cells[5] == "+5.33"
    assert cells[6] == "1.50"  # both ranges are 1.5 dB
    assert cells[7] == "3.6x"  # 5.33 / 1.5
    assert rows[2][5] == "+0.00" and rows[2][7] == "0.0x"  # the tongue did not change


def test_every_row_is_a_valid_config_and_the_beta_sweep_spans_standard_to_twenty():
    rows = wabe_scenario.rows(bleed=2)
    for name, knobs in rows.items():
        config = EditConfig(**knobs)
        assert config.editor_bleed == (0 if name.endswith("no_bleed") else 2)
    for opt in ("adam", "sgd"):
        betas = [EditConfig(**rows[wabe_scenario.beta_row(opt, b)]).beta
                 for b in wabe_scenario.BETAS]
        assert betas[0] == 0.0 and betas[-1] == 20.0 and betas == sorted(betas)
        assert all(EditConfig(**rows[wabe_scenario.beta_row(opt, b)]).blend == "wabe_grad"
                   for b in wabe_scenario.BETAS)
    assert EditConfig(**rows["none/code_mask/sgd"]).gradient_mask == "code"
    assert EditConfig(**rows["none/standard/sgd"]).optimizer == "sgd"
