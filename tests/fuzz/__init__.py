"""The CLI fuzzer (``python -m tests.fuzz.fuzz_cli``) and its tests."""
