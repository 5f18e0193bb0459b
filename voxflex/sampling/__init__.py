"""Quadrature samples (mid-point, Gauss-Legendre, elastons) and their volume moments."""
