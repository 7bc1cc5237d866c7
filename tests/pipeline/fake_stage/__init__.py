"""A stand-in stage package (tests/pipeline/test_integrity.py): ``stage`` holds its run."""
