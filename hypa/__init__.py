"""hypa: hybrid physics-augmented neural networks for dynamic systems with partially known physics."""

from hypa.data.schema import register_configs as _register_configs

# Before any entry point composes its configuration: conf/dataset/*.yaml start from this schema.
_register_configs()
