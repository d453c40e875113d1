"""MkDocs hooks: the Benchmarks page is the repository's BENCHMARKS.md, its image links (written relative to the
repository's root) made relative to the docs folder; the settings reference's table is drawn from the schema."""

from pathlib import Path

SETTINGS_TABLE = "<!-- every setting -->"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if SETTINGS_TABLE in markdown:
        from drrl.cli.settings import reference_table

        return markdown.replace(SETTINGS_TABLE, reference_table())
    if page.file.src_uri != "benchmarks.md":
        return markdown
    benchmarks = Path(config.config_file_path).parent / "BENCHMARKS.md"
    return benchmarks.read_text(encoding="utf-8").replace("](docs/images/", "](images/")
