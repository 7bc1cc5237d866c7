"""The contract between stages: schemas, workspace layout, atomic writer, validating reader."""

from manifests.io import (
    ManifestError,
    PartSink,
    clear,
    list_parts,
    open_sink,
    part_fingerprints,
    read_keys,
    read_manifest,
    read_success,
    remove_temporaries,
    to_table,
    validate_table,
    write_part,
    write_success,
)
from manifests.schema import MANIFESTS, SCHEMA_VERSION, Column, ManifestSpec
from manifests.workspace import Workspace

__all__ = [
    "MANIFESTS", "SCHEMA_VERSION", "Column", "ManifestError", "ManifestSpec", "PartSink", "Workspace", "clear",
    "list_parts", "open_sink", "part_fingerprints", "read_keys", "read_manifest", "read_success",
    "remove_temporaries", "to_table", "validate_table", "write_part", "write_success",
]
