"""Helpers shared by test modules (fake buses, run checks, scenes): no tests here, and no test module
imports another test module."""
