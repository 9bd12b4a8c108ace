"""Grey-box identification of physical parameters by their output (simulation) error."""

from hypa.identification.output_error import (
    Estimate,
    Identification,
    IdentificationError,
    IdentificationSettings,
    identify,
    identify_records,
)
from hypa.identification.stretches import Stretches

__all__ = ["Estimate", "Identification", "IdentificationError", "IdentificationSettings", "Stretches", "identify",
           "identify_records"]
