"""docs/formats.md documents every manifest's columns as the schema defines them."""

from pathlib import Path

from manifests.reference import layout, markdown
from manifests.schema import MANIFESTS

FORMATS = Path(__file__).resolve().parents[2] / "docs" / "formats.md"


def test_the_formats_document_holds_the_schemas_tables_as_generated():
    text = FORMATS.read_text()
    assert markdown() in text, "docs/formats.md is stale: paste `python -m manifests.reference` into it"
    for spec in MANIFESTS.values():
        assert f"### `{spec.name}`" in text
        assert all(f"| `{column.name}` |" in text for column in spec.columns)


def test_the_formats_document_holds_the_layout_as_generated():
    from manifests.workspace import LAYOUT

    assert layout() in FORMATS.read_text(), "docs/formats.md is stale: paste `python -m manifests.reference` into it"
    assert all(f"W/{path}" in layout() for path, _ in LAYOUT)


def test_the_formats_document_gives_each_json_files_version_as_the_code_has_it():
    from manifests.sidecars import (
        CALIBRATION_VERSION,
        FUSION_VERSION,
        MARKERS_VERSION,
        SESSION_VERSION,
        TRAJECTORIES_VERSION,
        TRUTH_VERSION,
    )

    text = " ".join(FORMATS.read_text().split())
    for name, version in (("session.json", SESSION_VERSION), ("calibration.json", CALIBRATION_VERSION),
                          ("fusion.json", FUSION_VERSION), ("truth.json", TRUTH_VERSION),
                          ("markers.json", MARKERS_VERSION), ("trajectories.json", TRAJECTORIES_VERSION)):
        assert f"`{name}` {version}" in text, name
