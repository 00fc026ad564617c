"""What is read from runs and robots: reports, statistics, plots, the 1-D theory, the
robot check and the benchmark."""
