"""What each fuzz/*/seeds.py does when run: its corpus written as fuzz/FAMILY/corpus/TARGET/NAME."""

from pathlib import Path


def write_corpus(family: Path, corpus: dict[str, dict[str, bytes]]) -> None:
    for target, files in corpus.items():
        folder = family / "corpus" / target
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in files.items():
            (folder / name).write_bytes(data)
