"""hypa: hybrid physics-augmented neural networks for dynamic systems with partially known physics."""
