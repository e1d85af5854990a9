"""Sources of data: synthetic datasets (Algorithm 8), gyro trajectories, the Wu-Shi
simulation and real recordings."""
