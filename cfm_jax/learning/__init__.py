"""Algorithm 1 of the paper: :mod:`.algorithm` holds the whole program; losses, networks
and forward models beside it. The loop, files and checkpoints: :mod:`cfm_jax.runs`."""
