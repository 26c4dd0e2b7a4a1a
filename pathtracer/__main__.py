"""``python -m pathtracer SCENE.xml -o OUT.exr``: the same as the ``pathtracer`` command."""

import sys

from pathtracer.cli import main

if __name__ == "__main__":
    sys.exit(main())
