"""The interactive viewer's parts: what a run or avatar folder holds (`source`), slider values
<-> FLAME parameters (`pose`), and one jitted frame (`frames`). `python -m gae_jax.view` wires
them to a browser page."""
