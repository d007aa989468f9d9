from gapsweep.cli import main

raise SystemExit(main())
