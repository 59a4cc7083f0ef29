"""Build tiny stand-in CUDA libraries so PyPI's (CUDA) torch wheel imports on a CPU-only box.

PyPI only ships CUDA builds of torch for linux/x86_64, and even libtorch_cpu.so
links against libcudart/libcupti.  The real NVIDIA runtime is several GB of
nvidia-* / cuda-* wheels, which a CPU benchmark never calls.  Instead, for every
CUDA shared library that torch's .so files NEED but that is not present, this
script compiles a stub .so with the same SONAME that defines every symbol torch
imports from it (with the same symbol version).  Every stub function returns
100 (cudaErrorNoDevice; a non-zero "failure" status for the other libraries),
and the *ErrorString/*ErrorName functions return a static message.  Hence
torch.cuda.is_available() is False and all CPU code paths work unchanged.

The stubs go into torch/lib (which is on the RPATH of every torch library).
Needs `readelf` (binutils) and `cc`.  Usage: python cuda_stubs.py TORCH_LIB_DIR
"""
import os
import re
import subprocess
import sys
import tempfile

STUB_MARK = "coadapt-cuda-stub"
# Loaded by torch only via dlopen when CUDA is used: not needed for CPU work.
SKIP_CONSUMERS = {"libcaffe2_nvrtc.so"}
# Unversioned symbols are assigned to a stub library by name prefix.
PREFIX_LIB = [
    ("cusparseLt", "libcusparseLt.so.0"),
    ("nccl", "libnccl.so.2"),
    ("cuFile", "libcufile.so.0"),
    ("nvshmem", "libnvshmem_host.so.3"),
    ("cudnn", "libcudnn.so.9"),
    ("cupti", "libcupti.so.13"),
]


def readelf(*args):
    return subprocess.run(["readelf", "-W", *args], check=True, capture_output=True, text=True).stdout


def needed(path):
    return re.findall(r"\(NEEDED\)\s+Shared library: \[([^\]]+)\]", readelf("-d", path))


def version_files(path):
    """Map version name -> library file from the .gnu.version_r section."""
    out, cur = {}, None
    for line in readelf("-V", path).splitlines():
        m = re.search(r"File: (\S+)", line)
        if m:
            cur = m.group(1)
        m = re.search(r"Name: (\S+)\s+Flags", line)
        if m and cur:
            out[m.group(1)] = cur
    return out


def dyn_syms(path):
    """(name, version or None, type, defined?) for each dynamic symbol."""
    rows = []
    for line in readelf("--dyn-syms", path).splitlines():
        f = line.split()
        if len(f) < 8 or not f[0].endswith(":"):
            continue
        name, ver = f[7], None
        if "@" in name:
            name, ver = name.split("@", 1)
            ver = ver.lstrip("@")
        rows.append((name, ver, f[3], f[6] != "UND", f[4]))
    return rows


def is_stub(path):
    if not os.path.isfile(path) or os.path.getsize(path) > 1 << 20:
        return False
    with open(path, "rb") as fh:
        return STUB_MARK.encode() in fh.read()


def system_libs():
    out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    return set(re.findall(r"^\s*(\S+) \(", out, re.M))


def main(lib_dir):
    lib_dir = os.path.abspath(lib_dir)
    pkg_dir = os.path.dirname(lib_dir)
    sos = [os.path.join(lib_dir, f) for f in os.listdir(lib_dir)
           if ".so" in f and f not in SKIP_CONSUMERS and not is_stub(os.path.join(lib_dir, f))]
    sos += [os.path.join(pkg_dir, f) for f in os.listdir(pkg_dir) if f.endswith(".so")]
    # Our own stubs from an earlier run count as missing, so they are rebuilt
    # for the torch that is installed now.
    ours = {f for f in os.listdir(lib_dir) if is_stub(os.path.join(lib_dir, f))}
    present = (set(os.listdir(lib_dir)) - ours) | system_libs()
    missing = set()
    for so in sos:
        for n in needed(so):
            if n not in present:
                missing.add(n)
    if not missing:
        print("cuda_stubs: no CUDA library is missing")
        return
    defined, wanted = set(), {}  # wanted[lib] = {name: (version, type)}
    unversioned = {}
    for so in sos:
        vfile = version_files(so)
        for name, ver, typ, is_def, bind in dyn_syms(so):
            if is_def:
                defined.add(name)
            elif ver and vfile.get(ver) in missing:
                wanted.setdefault(vfile[ver], {})[name] = (ver, typ)
            elif not ver and bind != "WEAK":
                unversioned[name] = typ
    # Unversioned imports that nothing in torch (or libc/libstdc++/python) defines.
    for name, typ in unversioned.items():
        if name in defined or name.startswith(("_Py", "Py", "_Z", "_ITM", "__gmon")):
            continue
        if not name.startswith(("cu", "nccl", "nvshmem", "__cuda")):
            continue
        lib = next((l for p, l in PREFIX_LIB if name.startswith(p)), "libcudart.so.13")
        if lib not in missing:
            lib = sorted(missing)[0]
        wanted.setdefault(lib, {}).setdefault(name, (None, typ))
    with tempfile.TemporaryDirectory() as tmp:
        for lib in sorted(missing):
            syms = wanted.get(lib, {})
            src = ['const char coadapt_stub_msg[] = "CUDA is not available (%s)";' % STUB_MARK]
            for name, (ver, typ) in sorted(syms.items()):
                if typ == "OBJECT":
                    src.append("char %s[256];" % name)
                elif re.search(r"Error(String|Name)$", name):
                    src.append("const char *%s(void) { return coadapt_stub_msg; }" % name)
                else:
                    src.append("long %s(void) { return 100; }" % name)
            c_path = os.path.join(tmp, lib + ".c")
            with open(c_path, "w") as fh:
                fh.write("\n".join(src) + "\n")
            versions = {}
            for name, (ver, _) in syms.items():
                versions.setdefault(ver, []).append(name)
            loose = versions.pop(None, [])
            if not versions:  # no symbol versioning: one anonymous node
                versions[""] = []
            first = sorted(versions)[0]
            versions[first] += loose  # unversioned imports bind to the default version
            script = ["%s { global: %s %s };" % (ver, " ".join(n + ";" for n in sorted(names)),
                                                "local: *;" if ver == first else "")
                      for ver, names in sorted(versions.items())]
            map_path = os.path.join(tmp, lib + ".map")
            with open(map_path, "w") as fh:
                fh.write("\n".join(script) + "\n")
            out = os.path.join(lib_dir, lib)
            subprocess.run(["cc", "-shared", "-fPIC", "-O1", "-o", out, c_path,
                            "-Wl,-soname," + lib, "-Wl,--version-script=" + map_path], check=True)
            print("cuda_stubs: %-24s %5d symbols" % (lib, len(syms)))


if __name__ == "__main__":
    main(sys.argv[1])
