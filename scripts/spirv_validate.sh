#!/usr/bin/env bash
# Every SPIR-V kernel CubeCL compiled in a run, checked by Khronos's validator: which ones a
# driver is given invalid code for. For the `vulkan` build (the wgpu runtime `wgpu<spirv>`).
#
#   CUBECL_DEBUG_LOG=/tmp/cubecl.log COMMAND...       # any run of a `--features vulkan` binary
#   bash scripts/spirv_validate.sh /tmp/cubecl.log    # one line per kernel: ok / INVALID, its name
#
# Needs spirv-as and spirv-val (Debian: `apt-get install spirv-tools`). Exits 1 when a kernel is
# invalid. Where the driver crashed building a pipeline, the log's last kernel is the one.
set -euo pipefail
log=${1:?usage: spirv_validate.sh CUBECL_LOG}
command -v spirv-val >/dev/null || { echo "spirv-val not found (Debian: apt-get install spirv-tools)" >&2; exit 2; }
python3 - "$log" <<'EOF'
import re, subprocess, sys, tempfile, os
text = open(sys.argv[1], encoding="utf-8", errors="replace").read()
blocks = text.split("[START_KERNEL_COMPILATION]")[1:]
bad = seen = 0
with tempfile.TemporaryDirectory() as tmp:
    asm, spv = os.path.join(tmp, "k.spvasm"), os.path.join(tmp, "k.spv")
    for b in blocks:
        name = re.search(r"name: (\S+)", b)
        name = name.group(1).rstrip("<") if name else "?"
        src = re.search(r"```spirv\n(.*?)```", b, re.S)
        if not src:
            continue
        seen += 1
        open(asm, "w").write(src.group(1))
        a = subprocess.run(["spirv-as", "--target-env", "vulkan1.3", asm, "-o", spv], capture_output=True, text=True)
        if a.returncode:
            print(f"INVALID  {name}: does not assemble: {a.stderr.strip().splitlines()[0]}")
            bad += 1
            continue
        v = subprocess.run(["spirv-val", "--target-env", "vulkan1.3", spv], capture_output=True, text=True)
        if v.returncode:
            print(f"INVALID  {name}: {v.stderr.strip().splitlines()[0]}")
            bad += 1
        else:
            print(f"ok       {name}")
print(f"{seen} SPIR-V kernels, {bad} invalid")
sys.exit(1 if bad else 0)
EOF
