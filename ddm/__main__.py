from ddm.cli import main

raise SystemExit(main())
