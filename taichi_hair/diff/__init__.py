"""Differentiable hair: reverse-mode gradients of a simulated motion (docs/differentiable.md)."""
