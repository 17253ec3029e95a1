"""Many edits, one process or many machines: `python -m gae_jax.batch JOBS.toml --out DIR`.

`manifest` reads the jobs, `runner` runs them in one process sharing what they can,
`summary` gathers their scores, `cluster` spreads them over Ray workers.
"""
