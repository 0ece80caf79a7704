"""A user's ``conf/`` in the current directory, searched ahead of the configs shipped in ``bench/conf``.

Why: the package's configs travel inside the wheel (``pkg://bench.conf``), which a user should not
edit; their own ``dataset/``, ``slam/``, ``experiment/`` and ``study/`` files (their KITTI root, a
study) go in ``./conf/`` instead, as in lightning-hydra-template. A file there with the name of a
shipped one replaces it; the run records which file each group choice came from
(``provenance.config_files``, from ``bench.run.lifecycle``). ``--config-dir DIR`` still adds DIR, after both.
"""

from __future__ import annotations

from hydra.core.config_search_path import ConfigSearchPath, SearchPathQuery
from hydra.plugins.search_path_plugin import SearchPathPlugin

from bench.conf import user_conf_dir


class UserConfSearchPath(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        conf = user_conf_dir()
        if conf is None:
            return
        main = [p for p in search_path.get_path() if p.provider == "main"]
        # ahead of the primary config dir (pkg://bench.conf), behind Hydra's own configs
        anchor = SearchPathQuery(provider="main") if main else None
        search_path.prepend(provider="pocketbench-user", path=f"file://{conf}", anchor=anchor)
