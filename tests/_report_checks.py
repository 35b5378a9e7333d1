"""What an HTML report shows and defines: the symbols of its tables and its glossary."""

import re

from openemt.report._glossary import PLAIN_WORDS


def shown_symbols(text: str) -> set:
    """Column names of every table and the symbol of every parameter row (``L_so`` of
    ``L_so[x, coil X]``, ``F_st`` of ``F_st.rx``), without plain words."""
    heads = {re.sub(r"<[^>]+>", "", h).replace("&amp;", "&")
             for h in re.findall(r"<th[^>]*>(.*?)</th>", text)}
    params = set(re.findall(r'<tr><td class="label">([A-Za-z]+_[A-Za-z]+)[\[.]', text))
    return (heads | params) - PLAIN_WORDS


def defined_symbols(text: str) -> set:
    """The terms of the report's glossary."""
    return set(re.findall(r"<dt>(.*?)</dt>", text))
