# SIGINT/SIGTERM are handled from the first statement on (issue 19): a signal while the modules load is
# recorded and acted on cleanly (gapsweep.sweep.limits.install_early), never a stale lease.
from gapsweep.sweep import limits

limits.install_early(defer_all=True)

from gapsweep.cli import main  # noqa: E402

raise SystemExit(main())
