"""What a manifest's ``[env]`` may give a decoder: plain data, never instructions to the
software that starts it.

A decoder gets a minimal environment (:func:`fbaconf.isolation.sandbox.decoder_env`); the
manifest's ``[env]`` adds variables to it. The dynamic loader, the C library, shells and every
language runtime read variables of their own as code to run first (``LD_PRELOAD``,
``PYTHONSTARTUP``, ``BASH_ENV``, ``PERL5OPT``, ``NODE_OPTIONS=--require``), as options
(``JAVA_TOOL_OPTIONS=-javaagent:…``, ``GODEBUG``, ``ASAN_OPTIONS``) or as a search path for code
(``PYTHONPATH`` → a ``sitecustomize.py``, ``LD_LIBRARY_PATH``, ``CLASSPATH``). Through them a
command that reads as the reference decoder (``{python} -m fbaconf.reference.decoder``) runs
the vendor's code first. So the rule, in two parts, both required:

1. **The name is not in a namespace that software reads its own settings from**: the
   dynamic loader's and the C library's (``LD_``, ``DYLD_``, ``GLIBC_``, ``MALLOC_``, ``GCONV_``…),
   the shells' (``BASH``, ``ENV``, ``SHELLOPTS``, ``IFS``…), every runtime's (``PYTHON``,
   ``JAVA``/``_JAVA``/``JDK_``/``CLASSPATH``, ``NODE_``/``NPM_``, ``PERL``, ``RUBY``/``GEM_``,
   ``GO…``/``CGO_``, ``DOTNET_``/``COMPLUS_``/``CORECLR_``, ``LUA``, ``R_``, ``PHP``, ``TCL``,
   ``OCAML``, ``ERL_``, ``JULIA_``), the sanitizers' (``ASAN_``…, whose reports the harness
   reads), the graphics and plug-in loaders' (``LIBGL_``, ``MESA_``, ``VK_``, ``__GL``, ``QT_``,
   ``GTK_``, ``GIO_``, ``XDG_``, ``OPENSSL_``), any name starting with ``_``, and the variables the
   harness sets itself (``PATH``, ``HOME``, ``TMPDIR``, ``LANG``, ``LC_``…) — listed in
   :data:`RESERVED`, one namespace per runtime.
2. **The value is data, not options**: no word that is an option or an argument file (starting
   with ``-`` or ``@``) and no ``name=value`` setting. This part holds for a runtime the list
   does not know: what it would obey arrives as an option or a setting. A path may be given:
   it reaches only what the sandbox shows anyway (the folders the command names, checked by
   :mod:`.view`) — the lab shows nothing because of ``[env]``.

``ACME_MODE = "strict"``, ``BUG = "sign"``, ``ACME_MODELS = "/opt/acme/models"`` pass.
"""

from __future__ import annotations

import re

# The namespaces software reads its own settings from (rule 1): an [env] name starting with
# one of these (compared in capitals) is refused. Exact names end with "=".
RESERVED = (
    # the dynamic loader, the C library, locale and resolver
    "LD_",
    "DYLD_",
    "GLIBC_",
    "MALLOC_",
    "GCONV_",
    "LOCPATH=",
    "NLSPATH=",
    "HOSTALIASES=",
    "RES_OPTIONS=",
    "LOCALDOMAIN=",
    "TZDIR=",
    # what the harness sets itself
    "PATH=",
    "HOME=",
    "TMPDIR=",
    "TMP=",
    "TEMP=",
    "LANG=",
    "LANGUAGE=",
    "LC_",
    "PWD=",
    "SHELL=",
    "USER=",
    # shells
    "BASH",
    "ENV=",
    "SHELLOPTS=",
    "PS4=",
    "IFS=",
    "CDPATH=",
    "PROMPT_COMMAND=",
    "ZDOTDIR=",
    # language runtimes
    "PYTHON",
    "VIRTUAL_ENV=",
    "JAVA",
    "JDK_",
    "JVM_",
    "CLASSPATH=",
    "NODE_",
    "NPM_",
    "PERL",
    "RUBY",
    "GEM_",
    "BUNDLE_",
    "GO",
    "CGO_",
    "DOTNET_",
    "COMPLUS_",
    "CORECLR_",
    "LUA",
    "R_",
    "PHP",
    "TCL",
    "TK_",
    "OCAML",
    "ERL_",
    "ELIXIR_",
    "JULIA_",
    "RUST_",
    "CARGO_",
    "WASM",
    # sanitizers (their reports are how the harness names a crash)
    "ASAN_",
    "UBSAN_",
    "MSAN_",
    "TSAN_",
    "LSAN_",
    "HWASAN_",
    # graphics, plug-in and configuration loaders
    "LIBGL_",
    "MESA_",
    "VK_",
    "EGL_",
    "GALLIUM_",
    "QT_",
    "GTK_",
    "GDK_",
    "GIO_",
    "GST_",
    "XDG_",
    "OPENSSL_",
    "SSL_",
    "DBUS_",
)
_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")


def _reserved(name: str) -> str | None:
    up = name.upper()
    if up.startswith("_"):
        return "_"
    for ns in RESERVED:
        if ns.endswith("=") and up == ns[:-1]:
            return ns[:-1]
        if ns == "GO" and re.fullmatch(r"GO[A-Z0-9]+", up):  # Go's own: GOGC, GODEBUG, GOMAXPROCS… (no "_")
            return "GO…"
        if ns != "GO" and not ns.endswith("=") and up.startswith(ns):
            return ns + "…"
    return None


def env_problem(name: str, value: str) -> str | None:
    """Why ``[env] name = value`` may not reach a decoder (the module's rule), or None."""
    if not _NAME.fullmatch(name):
        return f"{name[:40]!r} is not a variable name (a letter, then letters, digits or _; at most 64)"
    ns = _reserved(name)
    if ns is not None:
        return (
            f"{name} is in the {ns} namespace, which the loader, a shell or a runtime reads its own settings "
            f"from (code to run, options, a search path): [env] passes data to the decoder, never instructions "
            f"to what starts it"
        )
    word = next((w for w in value.split() if w[:1] in "-@" or "=" in w), None)
    if word is not None:
        return (
            f"{name}'s value holds {word[:40]!r}, an option, an argument file or a setting: [env] values are "
            f"data for the decoder, never options to what starts it"
        )
    if "\x00" in value or len(value) > 4096:
        return f"{name}'s value is not plain text of at most 4096 characters"
    return None
