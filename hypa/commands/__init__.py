"""The commands, ``hypa <command>`` (or ``python -m hypa <command>``): each composes its
configuration and calls the library. :mod:`hypa.commands.cli` lists them and runs one; each is a
module here with one shape, ``main(argv) -> exit status``, and also runs alone as
``python -m hypa.commands.<module>`` (how Lightning's ddp launcher starts the other ranks).

| command | module | what it does |
|---|---|---|
| ``hypa train`` | :mod:`hypa.commands.train` | train a model (or identify a physics-only one) |
| ``hypa evaluate`` | :mod:`hypa.commands.evaluate` | a trained run against its validation and test data |
| ``hypa simulate`` | :mod:`hypa.commands.simulate` | a physics model at its configured values against data |
| ``hypa diagnose`` | :mod:`hypa.commands.diagnose` | what the physics gets wrong, named, and the extended model |
| ``hypa fleet`` | :mod:`hypa.commands.fleet` | the diagnosis over a fleet of logs, and its summary |
| ``hypa explain`` | :mod:`hypa.commands.explain` | a trained network explained by physical forms |
| ``hypa benchmark`` | :mod:`hypa.commands.benchmark` | every model of a data set over seeds, beside published figures |
| ``hypa reproduce`` | :mod:`hypa.commands.reproduce` | the paper's Table 1 |
| ``hypa export`` | :mod:`hypa.commands.export` | a trained model as ONNX, an FMU or state space, checked |
| ``hypa testbench`` | :mod:`hypa.commands.testbench` | the paper's simulated test-bench data |
| ``hypa timing`` | :mod:`hypa.commands.timing` | how fast the physics and the diagnosis are |

Importing this package, or a command's module, registers nothing: :mod:`hypa.commands.config`
holds each command's configuration as a typed tree (Hydra structured configs) and
:func:`~hypa.commands.config.register_configs` stores them, with the configurations' resolvers,
before a command composes (each command's ``main`` calls it; code that composes a configuration
itself, ``hydra.compose`` in a test, calls it first). :mod:`hypa.commands.entry` turns configuration
nodes into the library's objects; nothing below the commands imports this package.
"""
