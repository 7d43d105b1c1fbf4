"""Regenerate docs/design.md's options tables from the declarations (each after its marker).

Run from the repository's root after changing an option: ``python docs/options_tables.py``.
"""
import re
from pipeline import settings
p='docs/design.md'
s=open(p).read()
def table_after(m):
    cls=getattr(settings, m.group(1))
    return m.group(0).split('\n')[0]+'\n'+cls.table()
s=re.sub(r"<!-- options table: (\w+) [^\n]*-->\n(\|[^\n]*\n)+", lambda m: table_after(m)+'\n', s)
open(p,'w').write(s)
print(f"{p}: options tables made from pipeline/settings")
