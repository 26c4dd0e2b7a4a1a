"""``python -m pathtracer SCENE.xml -o OUT.exr``: the same as the ``pathtracer`` command."""

from pathtracer.cli import entry

if __name__ == "__main__":
    entry()
