"""MkDocs hook: the Benchmarks page is the repository's BENCHMARKS.md, its image links (written relative to the
repository's root) made relative to the docs folder."""

from pathlib import Path


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.src_uri != "benchmarks.md":
        return markdown
    benchmarks = Path(config.config_file_path).parent / "BENCHMARKS.md"
    return benchmarks.read_text(encoding="utf-8").replace("](docs/images/", "](images/")
