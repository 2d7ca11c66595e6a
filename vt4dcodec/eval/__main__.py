"""``python -m vt4dcodec.eval``: evaluate models on held-out synthetic scenes (see :mod:`.command`)."""

from .command import main

raise SystemExit(main())
