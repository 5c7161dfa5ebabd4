"""A small reader of a PDF's logical structure (tagged PDF), for the report's tests.

Neither pypdf nor pikepdf is a dependency, so this reads the raw objects itself: every
``N G obj`` of the file, and the objects packed into compressed object streams
(``/Type /ObjStm``, which WeasyPrint writes), parsed into Python values. Enough of the
PDF syntax (ISO 32000-1 §7.3) for what WeasyPrint writes: dictionaries, arrays, names,
literal and hex strings, numbers, references, booleans and null. It does not follow an
incremental update's xref chain: the last definition of an object number wins, as in a
file written once.
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Ref:
    """An indirect reference ``N G R``."""

    num: int
    gen: int = 0


class Name(str):
    """A PDF name, without its slash (``/Figure`` → ``Name("Figure")``)."""


_DELIM = b"()<>[]{}/%"
_WS = b" \t\r\n\x0c\x00"
_ESCAPES = {ord("n"): b"\n", ord("r"): b"\r", ord("t"): b"\t", ord("b"): b"\b",
            ord("f"): b"\x0c", ord("("): b"(", ord(")"): b")", ord("\\"): b"\\"}
_NUMBER = re.compile(rb"[+-]?(\d+\.?\d*|\.\d+)")


def _text(raw: bytes) -> str:
    """A PDF text string: UTF-16 with a byte-order mark, else PDFDocEncoding (~Latin-1)."""
    if raw[:2] in (b"\xfe\xff", b"\xff\xfe"):
        return raw.decode("utf-16")
    if raw[:3] == b"\xef\xbb\xbf":
        return raw[3:].decode("utf-8")
    return raw.decode("latin-1")


class _Parser:
    def __init__(self, data: bytes, pos: int = 0) -> None:
        self.data, self.pos = data, pos

    def _skip(self) -> None:
        d = self.data
        while self.pos < len(d):
            c = d[self.pos]
            if c in _WS:
                self.pos += 1
            elif c == ord("%"):
                while self.pos < len(d) and d[self.pos] not in b"\r\n":
                    self.pos += 1
            else:
                return

    def _token(self) -> bytes:
        start = self.pos
        while self.pos < len(self.data) and self.data[self.pos] not in _WS + _DELIM:
            self.pos += 1
        return self.data[start:self.pos]

    def value(self) -> Any:
        self._skip()
        d, c = self.data, self.data[self.pos:self.pos + 2]
        if c == b"<<":
            self.pos += 2
            out: dict[str, Any] = {}
            while True:
                self._skip()
                if d[self.pos:self.pos + 2] == b">>":
                    self.pos += 2
                    return out
                key = self.value()
                out[str(key)] = self.value()
        if c[:1] == b"[":
            self.pos += 1
            arr: list[Any] = []
            while True:
                self._skip()
                if d[self.pos:self.pos + 1] == b"]":
                    self.pos += 1
                    return arr
                arr.append(self.value())
        if c[:1] == b"/":
            self.pos += 1
            return Name(re.sub(rb"#([0-9a-fA-F]{2})", lambda m: bytes([int(m[1], 16)]),
                               self._token()).decode("latin-1"))
        if c[:1] == b"(":
            return self._literal()
        if c[:1] == b"<":
            end = d.index(b">", self.pos)
            hexs = re.sub(rb"\s", b"", d[self.pos + 1:end])
            self.pos = end + 1
            return _text(bytes.fromhex((hexs + b"0" * (len(hexs) % 2)).decode()))
        m = _NUMBER.match(d, self.pos)
        if m:
            self.pos = m.end()
            num: int | float = float(m[0]) if b"." in m[0] else int(m[0])
            # "N G R" is a reference
            ref = re.compile(rb"\s+(\d+)\s+R(?![^\s/\[\]<>()])").match(d, self.pos)
            if isinstance(num, int) and ref:
                self.pos = ref.end()
                return Ref(num, int(ref[1]))
            return num
        word = self._token()
        if not word:
            raise ValueError(f"PDF syntax error at byte {self.pos}: {d[self.pos:self.pos + 20]!r}")
        return {b"true": True, b"false": False, b"null": None}.get(word, word.decode("latin-1"))

    def _literal(self) -> str:
        d, out, depth = self.data, bytearray(), 0
        self.pos += 1
        while True:
            c = d[self.pos]
            self.pos += 1
            if c == ord("\\"):
                e = d[self.pos]
                if e in _ESCAPES:
                    out += _ESCAPES[e]
                    self.pos += 1
                elif chr(e).isdigit():
                    m = re.compile(rb"[0-7]{1,3}").match(d, self.pos)
                    assert m is not None
                    out.append(int(m[0], 8) & 0xFF)
                    self.pos = m.end()
                else:  # a line continuation or an unknown escape: dropped
                    self.pos += 1 if e not in b"\r\n" else 0
                continue
            if c == ord("("):
                depth += 1
            elif c == ord(")"):
                if depth == 0:
                    return _text(bytes(out))
                depth -= 1
            out.append(c)


_OBJ = re.compile(rb"(?<![0-9])(\d+)\s+(\d+)\s+obj\b")


@dataclass
class PdfObjects:
    """Every object of a PDF by number, and its trailer (or xref stream dictionary)."""

    objects: dict[int, Any] = field(default_factory=dict)
    trailer: dict[str, Any] = field(default_factory=dict)
    #: the decoded data of each stream object, by object number
    streams: dict[int, bytes] = field(default_factory=dict)

    def get(self, v: Any) -> Any:
        """``v`` itself, or the object it refers to."""
        while isinstance(v, Ref):
            v = self.objects.get(v.num)
        return v

    @property
    def catalog(self) -> dict[str, Any]:
        """The document catalog (``/Root``)."""
        root = self.get(self.trailer.get("Root"))
        assert isinstance(root, dict), "no document catalog"
        return root


def read_objects(pdf: bytes) -> PdfObjects:
    """Parse every object of ``pdf``, with those inside object streams."""
    out = PdfObjects()
    streams: list[tuple[dict[str, Any], bytes]] = []
    done = 0  # end of the last stream read: "N G obj" inside its bytes is no object
    for m in _OBJ.finditer(pdf):
        if m.start() < done:
            continue
        p = _Parser(pdf, m.end())
        try:
            val = p.value()
        except (ValueError, IndexError):
            continue  # "N G obj" inside binary data that is not an object
        p._skip()
        if isinstance(val, dict) and pdf.startswith(b"stream", p.pos):
            start = p.pos + len(b"stream")
            start += 2 if pdf[start:start + 2] == b"\r\n" else 1
            length = out.get(val.get("Length")) if not isinstance(val.get("Length"), Ref) \
                else None
            raw = (pdf[start:start + length] if isinstance(length, int)
                   else pdf[start:pdf.index(b"endstream", start)])
            done = start + len(raw)
            if val.get("Filter") == "FlateDecode":
                raw = zlib.decompress(raw)
            streams.append((val, raw))
            out.streams[int(m[1])] = raw
            if val.get("Type") == "XRef":
                out.trailer = val
        out.objects[int(m[1])] = val
    for d, raw in streams:
        if d.get("Type") != "ObjStm":
            continue
        head = raw[:d["First"]].split()
        for k in range(0, 2 * d["N"], 2):
            num, off = int(head[k]), int(head[k + 1])
            out.objects[num] = _Parser(raw, d["First"] + off).value()
    if not out.trailer:
        t = pdf.rfind(b"trailer")
        if t >= 0:
            out.trailer = _Parser(pdf, t + len(b"trailer")).value()
    return out


@dataclass
class StructElem:
    """One element of the structure tree: its type, attributes and children in order."""

    type: str
    alt: str | None
    attrs: dict[str, Any]
    kids: list[StructElem]
    text_ids: list[int]  # marked-content ids of the content it holds directly
    id: str | None = None  # its /ID (a table header cell's, which /Headers name)

    def walk(self) -> list[StructElem]:
        """This element and all below it, in reading (document) order."""
        out = [self]
        for k in self.kids:
            out += k.walk()
        return out

    def find(self, type_: str) -> list[StructElem]:
        """Every element of ``type_`` at or below this one, in reading order."""
        return [e for e in self.walk() if e.type == type_]


def structure_tree(objs: PdfObjects) -> StructElem:
    """The structure tree from the catalog's ``/StructTreeRoot``.

    Raises:
        AssertionError: the PDF is not tagged.
    """
    root = objs.get(objs.catalog.get("StructTreeRoot"))
    assert isinstance(root, dict) and root.get("Type") == "StructTreeRoot", "not a tagged PDF"
    seen: set[int] = set()

    def elem(v: Any) -> StructElem | None:
        if isinstance(v, Ref):
            if v.num in seen:
                raise AssertionError(f"structure tree has a cycle at object {v.num}")
            seen.add(v.num)
        d = objs.get(v)
        if not isinstance(d, dict) or d.get("Type") not in (None, "StructElem",
                                                            "StructTreeRoot"):
            return None  # a marked-content reference or an annotation
        kids_raw = objs.get(d.get("K"))
        kids_list = kids_raw if isinstance(kids_raw, list) else [kids_raw]
        kids = [e for k in kids_list if (e := elem(k)) is not None]
        mcids = [k for k in kids_list if isinstance(k, int)]
        attrs = objs.get(d.get("A")) or {}
        return StructElem(str(d.get("S", "StructTreeRoot")), d.get("Alt"),
                          attrs if isinstance(attrs, dict) else {}, kids, mcids,
                          d.get("ID"))

    tree = elem(objs.catalog["StructTreeRoot"])
    assert tree is not None
    return tree
