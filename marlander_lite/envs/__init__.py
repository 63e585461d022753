"""Environment faces shared by both simulators: gymnasium, PettingZoo, and the option parsing."""
