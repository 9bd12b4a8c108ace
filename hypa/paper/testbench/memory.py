"""Whether the test bench's settings fit into this machine: checked before anything is generated.

The settings size the data (records x their durations x the sample rate), so a setting, or a
run folder's stored configuration that someone sent, can ask for more samples than the machine
can hold; generating them would end in a ``MemoryError`` (or the kernel's out-of-memory killer)
after minutes. :func:`check_fits` compares what they ask for with this machine's available
memory first and refuses in one line that names the settings to lower.
"""

from __future__ import annotations

import math

from hypa.core.errors import UserError
from hypa.core.machine import available_memory
from hypa.paper.testbench.config import KEY, MANEUVERS, TestbenchConfig

# What one sample costs [bytes]. The files hold the time and six channels as float64, and so does
# the data that a command reads from them. Simulating a record holds, per sample, the excitation and
# its FFTs, the truth's Python float lists (the RK4 loop runs on Python floats: 32 bytes per value
# and list slot) and the measured channels: about 220 bytes at the peak (tracemalloc); twice that,
# for the allocator's slack.
FILE_BYTES_PER_SAMPLE = 7 * 8
SIMULATION_BYTES_PER_SAMPLE = 512
SHARE = 0.5  # of the available memory the test bench may ask for


def record_samples(config: TestbenchConfig) -> dict[str, float]:
    """Samples of each record [-] as the generator makes them: the stochastic part, then the
    manoeuvres (floats: a value too large to generate is still compared, not allocated)."""
    fs = config.sample_rate_hz
    return {str(name): float(record.stochastic_duration_s) * fs
            + sum(getattr(config.excitation, m).duration_s * fs for m in record.maneuvers)
            for name, record in config.records.items()}


def needed_bytes(config: TestbenchConfig) -> float:
    """Bytes that generating ``config`` and reading its files back take: every record's samples as
    files, plus the simulation of the longest one (records are simulated one after the other)."""
    samples = record_samples(config).values()
    return sum(samples) * FILE_BYTES_PER_SAMPLE + max(samples, default=0.0) * SIMULATION_BYTES_PER_SAMPLE


def check_fits(config: TestbenchConfig, available: int | None = None) -> None:
    """Refuse, in one line, settings whose data would need more than :data:`SHARE` of the memory
    available to this process (``available`` [bytes]: :func:`available_memory`); nothing is allocated."""
    available = available_memory() if available is None else available
    if available is None:
        return
    need = needed_bytes(config)
    if need <= SHARE * available:
        return
    samples = record_samples(config)
    longest = max(samples, key=samples.__getitem__)
    record, fs = config.records[longest], config.sample_rate_hz
    parts = {f"{KEY}.records.{longest}.stochastic_duration_s": record.stochastic_duration_s,
             **{f"{KEY}.excitation.{m}.duration_s": getattr(config.excitation, m).duration_s
                for m in MANEUVERS if m in record.maneuvers}}
    setting = max(parts, key=parts.__getitem__)
    total, most = sum(samples.values()), samples[longest]
    raise UserError(f"{KEY}: the settings ask for {_count(total)} samples in {len(samples)} record(s) ({longest}: "
                    f"{_count(most)} samples, {most / fs:.3g} s at {KEY}.sample_rate_hz={fs:g}), "
                    f"about {_gib(need)} GiB to generate and read, more than half of the {_gib(available)} GiB "
                    f"of memory available here; lower {setting} or {KEY}.sample_rate_hz")


def _count(samples: float) -> str:
    """12345678 -> ``1.23e+07``; small counts as integers."""
    return f"{samples:.3g}" if not math.isfinite(samples) or samples >= 1e6 else f"{round(samples):d}"


def _gib(size: float) -> str:
    """Bytes in GiB as read: 5418 GiB with a thousands separator, 21.3 GiB."""
    gib = size / 2.0**30
    return f"{gib:,.0f}" if gib >= 100 else f"{gib:.3g}"
