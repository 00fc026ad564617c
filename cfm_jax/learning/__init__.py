"""The learning algorithm, Algorithm 1 of the paper: :mod:`.algorithm` holds the whole
program (init, one iteration = collect + refit the forward model + refit the controller,
evaluate), :mod:`.losses` the controller losses (``register`` adds your own),
:mod:`.networks` the controller and forward networks, :mod:`.forward_models` the forward
model kinds (``register``) with the rigid-body one in :mod:`.rigid_body`. Pure and
jit-able; the loop, files and checkpoints are in :mod:`cfm_jax.runs`."""
