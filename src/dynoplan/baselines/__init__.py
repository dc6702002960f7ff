"""Baselines that are not option choosers: a flat end-to-end RL policy (Stable-Baselines3)."""
