#!/usr/bin/env python3
"""Write config/map_merge.yaml and the README's parameter table (between its markers) from the
parameter tables, src/multi_map_merge/core/parameters.py and src/multi_map_merge/node_config.py
(through multi_map_merge.cli.params_doc): run after editing them.

    python3 tools/gen_params.py           # write both
    python3 tools/gen_params.py --check   # exit 1 when a committed file differs (as the unit test)
"""
import argparse
import os
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, 'src'))

from multi_map_merge.cli import params_doc  # noqa: E402

YAML = os.path.join(REPO, 'config', 'map_merge.yaml')
README = os.path.join(REPO, 'README.md')


def generated():
    """{path: the text it should have}"""
    with open(README) as f:
        readme = f.read()
    return {YAML: params_doc.yaml_text(), README: params_doc.replace_readme_block(readme)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--check', action='store_true', help='only compare; exit 1 when a file differs')
    a = ap.parse_args()
    stale = []
    for path, text in generated().items():
        with open(path) as f:
            if f.read() == text:
                continue
        stale.append(os.path.relpath(path, REPO))
        if not a.check:
            with open(path, 'w') as f:
                f.write(text)
    if stale:
        print('%s: %s' % ('differ from the tables' if a.check else 'written', ', '.join(stale)))
    return 1 if stale and a.check else 0


if __name__ == '__main__':
    sys.exit(main())
