"""Sparse Levenberg-Marquardt with Schur-complement elimination, shared by every refiner."""

from core.optim._sparse_lm import SparseLMResult, SparseProblem, solve_sparse_lm

__all__ = ["SparseLMResult", "SparseProblem", "solve_sparse_lm"]
