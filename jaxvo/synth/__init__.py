"""Synthetic dynamic RGB-D scenes with exact ground truth: ``scenes`` (the scenarios,
sequences and composites, host) and ``render`` (their JAX ray caster)."""
