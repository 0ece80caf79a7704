"""The 3D viewer (``pocketbench view``, ``python -m bench.view``): ``scene`` reads run dirs into arrays, ``serve``
draws them with viser (the optional extra ``view``), ``cli`` is the command."""
