"""MkDocs hook: the Markdown and figures under ``reports/`` and ``datasets/`` become pages of the site.

They stay where they are in the repository and keep their repository-relative links: a docs page links
``../reports/known_limits.md`` (which also works when the Markdown is read on a forge), and this hook
registers each such file under that very path (``src_uri`` ``../reports/...``, relative to ``docs/``).
The site writes it to ``reports/...``. Links inside those files are then checked like any page's,
so a broken link or anchor in a report fails the strict build too.
"""

from __future__ import annotations

from pathlib import Path

from mkdocs.structure.files import File, Files, InclusionLevel

MOUNTED = ("reports", "datasets")
SUFFIXES = {".md", ".png", ".svg", ".csv", ".tex"}


def on_files(files: Files, config) -> Files:
    root = Path(config.config_file_path).resolve().parent
    for folder in MOUNTED:
        for path in sorted((root / folder).rglob("*")):
            if not path.is_file() or path.suffix not in SUFFIXES:
                continue
            rel = path.relative_to(root).as_posix()
            # where the site puts it: as if it were docs/<rel> (README.md becomes the folder's index)
            site = File(rel, src_dir=str(root), dest_dir=config.site_dir, use_directory_urls=config.use_directory_urls)
            files.append(
                File(
                    f"../{rel}",
                    src_dir=config.docs_dir,
                    dest_dir=config.site_dir,
                    use_directory_urls=config.use_directory_urls,
                    dest_uri=site.dest_uri,
                    inclusion=InclusionLevel.INCLUDED,
                )
            )  # a leading '..' is not a dotfile
    return files
