"""Experiments wire library parts together; they hold no library logic of their own."""
