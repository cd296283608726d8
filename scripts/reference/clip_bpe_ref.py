#!/usr/bin/env python3
"""Independent reference for CLIP's byte-level BPE tokenizer (what Stable Diffusion's text
encoders read), in plain Python, from a model's `vocab.json` and `merges.txt`.

Written from the algorithm of CLIP's tokenizer (Radford et al. 2021), not from any
tokenizer library, so that the Rust tokenizer (the `tokenizers` crate reading the
model's `tokenizer.json`) and the Python one used at export time can both be checked
against it:

0. strings the tokenizer holds as special tokens (beyond the start/end marks) are cut
   out first and become one token each;
1. text -> NFC -> runs of whitespace to one space -> lower case;
2. split into words with CLIP's pattern (contractions, letter runs, single digits,
   runs of other non-space characters);
3. each word's UTF-8 bytes mapped to printable characters (the GPT-2 byte table), the
   last one marked as a word end (`</w>`);
4. repeatedly merge the adjacent pair of lowest merge rank until none is in the table;
5. ids: <|startoftext|>, the word pieces, <|endoftext|>, truncated to `max_length`
   (keeping both specials) and padded with `pad_id` to `max_length`.

Differences from OpenAI's original: no ftfy / HTML unescaping (the Hugging Face
tokenizer that diffusers uses does neither).

    python scripts/reference/clip_bpe_ref.py DIR "a prompt" [...]   # prints ids

DIR holds vocab.json and merges.txt. Also used by scripts/export_models.py to write
the token-id golden file of a test fixture (reference/tokens.json).
"""
import json
import os
import sys
import unicodedata

import regex

PATTERN = regex.compile(
    r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""
)
BOS, EOS = "<|startoftext|>", "<|endoftext|>"


def byte_table():
    """GPT-2's reversible byte -> printable character map (256 entries)."""
    keep = list(range(ord("!"), ord("~") + 1)) + list(range(0xA1, 0xAC + 1)) + \
        list(range(0xAE, 0xFF + 1))
    chars = {b: chr(b) for b in keep}
    extra = 0
    for b in range(256):
        if b not in chars:
            chars[b] = chr(256 + extra)
            extra += 1
    return chars


def base_vocab():
    """The 512 single-character tokens in CLIP's order: each byte character, then the
    same with the word-end mark."""
    chars = list(byte_table().values())
    return chars + [c + "</w>" for c in chars]


def word_symbols(word, table):
    s = [table[b] for b in word.encode("utf-8")]
    s[-1] = s[-1] + "</w>"
    return s


def bpe(symbols, ranks):
    symbols = list(symbols)
    while len(symbols) > 1:
        best = None
        for i in range(len(symbols) - 1):
            r = ranks.get((symbols[i], symbols[i + 1]))
            if r is not None and (best is None or r < best[0]):
                best = (r, i)
        if best is None:
            break
        a, b = symbols[best[1]], symbols[best[1] + 1]
        merged, i = [], 0
        while i < len(symbols):
            if i < len(symbols) - 1 and symbols[i] == a and symbols[i + 1] == b:
                merged.append(a + b)
                i += 2
            else:
                merged.append(symbols[i])
                i += 1
        symbols = merged
    return symbols


def normalize(text):
    text = unicodedata.normalize("NFC", text)
    return regex.sub(r"\s+", " ", text).lower()


class ClipBpe:
    """`specials`: further strings the tokenizer treats as single special tokens, matched
    before word splitting (SDXL's second tokenizer pads with `!` and so reads every `!`
    as that token, id 0, rather than as the word piece `!</w>`)."""

    def __init__(self, vocab, merges, specials=()):
        self.vocab = vocab
        self.ranks = {tuple(m): i for i, m in enumerate(merges)}
        self.table = byte_table()
        self.specials = sorted(set(specials) - {BOS, EOS}, key=len, reverse=True)

    @classmethod
    def load(cls, d, specials=()):
        with open(os.path.join(d, "vocab.json"), encoding="utf-8") as f:
            vocab = json.load(f)
        with open(os.path.join(d, "merges.txt"), encoding="utf-8") as f:
            lines = [ln.rstrip("\n") for ln in f]
        merges = [tuple(ln.split(" ")) for ln in lines if ln and not ln.startswith("#version")]
        return cls(vocab, merges, specials)

    def pieces(self, text):
        if self.specials:
            split = regex.compile("(" + "|".join(regex.escape(t) for t in self.specials) + ")")
            parts = split.split(text)
        else:
            parts = [text]
        out = []
        for i, part in enumerate(parts):
            if i % 2 == 1:  # a special token
                out.append(part)
            else:
                out.extend(self.word_pieces(part))
        return out

    def word_pieces(self, text):
        out = []
        for word in PATTERN.findall(normalize(text)):
            if word in (BOS, EOS):
                out.append(word)
                continue
            out.extend(bpe(word_symbols(word, self.table), self.ranks))
        return out

    def encode(self, text, max_length=77, pad_id=None):
        unk = self.vocab[EOS]
        ids = [self.vocab.get(p, unk) for p in self.pieces(text)]
        ids = [self.vocab[BOS]] + ids[: max_length - 2] + [self.vocab[EOS]]
        if pad_id is not None:
            ids += [pad_id] * (max_length - len(ids))
        return ids


def train_merges(words, n_merges):
    """Learn `n_merges` BPE merges from a word list (most frequent adjacent pair first,
    ties broken by the pair's text): how the tiny test fixtures get a CLIP-format
    vocabulary of a few hundred tokens instead of CLIP's 49,408."""
    table = byte_table()
    counts = {}
    for w in words:
        key = tuple(word_symbols(w, table))
        counts[key] = counts.get(key, 0) + 1
    merges, made = [], set(base_vocab())
    for _ in range(n_merges):
        pairs = {}
        for syms, c in counts.items():
            for p in zip(syms, syms[1:]):
                if p[0] + p[1] not in made:  # one token per merged string
                    pairs[p] = pairs.get(p, 0) + c
        if not pairs:
            break
        best = min(pairs.items(), key=lambda kv: (-kv[1], kv[0]))[0]
        merges.append(best)
        made.add(best[0] + best[1])
        new = {}
        for syms, c in counts.items():
            s = bpe(syms, {best: 0})
            new[tuple(s)] = new.get(tuple(s), 0) + c
        counts = new
    return merges


def vocab_from_merges(merges):
    toks = base_vocab() + ["".join(m) for m in merges] + [BOS, EOS]
    return {t: i for i, t in enumerate(toks)}


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    tok = ClipBpe.load(sys.argv[1])
    for t in sys.argv[2:]:
        print(json.dumps(tok.encode(t)))
