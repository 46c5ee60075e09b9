"""``python -m camera_service CONFIG.yaml``: the camera service (see camera_service.cli)."""

import sys

from camera_service.cli import main

sys.exit(main())
