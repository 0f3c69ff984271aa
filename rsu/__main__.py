from rsu.cli import main

raise SystemExit(main())
