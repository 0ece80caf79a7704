"""Settings, the layer under everything they configure: the rule on each setting's field (``settings``)
and the plugin lookup over entry points (``plugins``). A run's composition of them (``RunConfig``), its
validation and its identity sit above what they compose, in ``bench.run``."""
