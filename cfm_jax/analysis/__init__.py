"""What is read from runs and robots: :mod:`.report` (summaries and tables of a run),
:mod:`.stats` (paired tests, intervals, Holm), :mod:`.plots`, the paper's 1-D theory
(:mod:`.theory`), ``cfm-jax robot check`` (:mod:`.robot_check`), the benchmark and its
PyTorch reference (:mod:`.bench`, :mod:`.torch_reference`) and TensorBoard event files
(:mod:`.tensorboard`)."""
