"""Register-level chip simulators with a physical error model: the test bench for the drivers."""
