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
    remove_temporaries,
    to_table,
    validate_table,
    write_part,
)
from manifests.marker import CompletionMarker, read_marker, write_marker
from manifests.schema import MANIFESTS, SCHEMA_VERSION, Column, ManifestSpec
from manifests.workspace import Workspace

__all__ = [
    "MANIFESTS", "SCHEMA_VERSION", "Column", "CompletionMarker", "ManifestError", "ManifestSpec", "PartSink",
    "Workspace", "clear", "list_parts", "open_sink", "part_fingerprints", "read_keys", "read_manifest", "read_marker",
    "remove_temporaries", "to_table", "validate_table", "write_marker", "write_part",
]
