"""Settings: composition and the run config's dataclasses (``compose``), the rule on each setting's field
(``settings``), what identifies a run (``identity``), the plugin lookup over entry points (``plugins``)."""
