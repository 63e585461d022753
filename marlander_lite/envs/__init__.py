"""Environment faces shared by every simulator (gymnasium, stable-baselines3, PettingZoo) and their options."""
