"""docs/models.md's contract tables are the code's: generated from the keys the parsers
read, and every key the parsers read or the exporters write is in them."""

import re
from pathlib import Path

import numpy as np

from stages.common import contract_tables, detector, model_contract

ROOT = Path(__file__).resolve().parents[3]


def test_the_models_document_holds_the_generated_tables():
    text = (ROOT / "docs" / "models.md").read_text()
    for block in contract_tables.BLOCKS:
        assert contract_tables.markdown(block) in text, \
            f"docs/models.md is stale: paste `python -m stages.common.contract_tables`'s {block} into it"


def test_the_tables_name_every_key_the_code_reads_or_writes():
    for module, keys in ((model_contract, model_contract.CONTRACT_KEYS), (detector, detector.DETECTOR_KEYS)):
        source = Path(module.__file__).read_text()
        code = source[source.index('"""', 3) + 3:]  # past the module docstring
        used = set(re.findall(r'"(speedplus\.[a-z_]+)"', code)) - {"speedplus.recipe", "speedplus.variant",
                                                                   "speedplus.augmentation"}
        assert used == set(keys), (module.__name__, used ^ set(keys))
    written = model_contract.ModelContract(192, 192, "gray", (0.5,), (0.25,), "heatmaps", np.zeros((11, 3)),
                                       "oracle_box", 4, "boulder").metadata()
    assert set(written) <= set(model_contract.CONTRACT_KEYS)
    written = detector.DetectorContract(192, 128, "gray", (0.5,), (0.25,), "boulder", 1.2).metadata()
    assert set(written) == set(detector.DETECTOR_KEYS)
