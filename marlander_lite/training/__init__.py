"""PPO training of MARLander policies: presets, the training loop, logs and export."""
