#!/usr/bin/env python3
"""The Kubernetes Jobs in scripts/, tested without a cluster (no Kubernetes server can be
installed from the registries this project reaches):

1. Each Job is validated, strictly, against Kubernetes' own OpenAPI schema (the PyPI package
   kubernetes-validate, which ships the schemas): a misspelt or misplaced field fails.
2. Each Job is run by an emulation of the Job controller's rules that it relies on, with the
   project's real binaries and the container's own command (image paths mapped onto a
   temporary folder that stands for the persistent volume):
   - train_k8s_job.yaml: pod 1 gets SIGTERM mid-run (what a node drain, eviction or preemption
     delivers), pod 2 SIGKILL (a crash: it must count against backoffLimit), pod 3 SIGTERM
     again, pod 4 runs to the end. Each pod's exit is judged by the Job's podFailurePolicy;
     every pod must stop within terminationGracePeriodSeconds; the Job must complete within
     backoffLimit, with the same metrics.jsonl as an uninterrupted run, and its log must carry
     plain progress lines.
   - train_k8s_mpijob.yaml (an MPIJob of the Kubeflow training operator, data-parallel): its
     fields are checked against the operator's API (the models of its PyPI SDK,
     kubeflow-training: a misspelt field fails) and each replica's pod template against
     Kubernetes' schema; mpirun's rank count must equal Worker replicas × slotsPerWorker. The
     launcher's command is then run with the MPI trainer (--mpi-trainer), ranks on this machine:
     SIGTERM to the launcher mid-run (a drain), SIGKILL to a rank (a worker lost), then a run
     to the end; each restart counts against runPolicy.backoffLimit, and the result must equal
     a one-process run within the rank tests' tolerance. Skipped, saying so, without the MPI
     trainer, mpirun or kubeflow-training.
   - datagen_k8s_job.yaml (an Indexed Job): the worker count in the command must equal
     `completions`; shrunk to 4 indices of a small manifest, run all at once (parallelism), and
     again one at a time with index 2 killed between its shards and retried
     (backoffLimitPerIndex); both joined datasets must be byte-identical to a single-process
     run.

    python3 scripts/test_k8s_jobs.py [--trainer PATH] [--datagen PATH] [--mpi-trainer PATH] [--keep]

Without PyYAML and kubernetes-validate (pip install kubernetes-validate) it says so and skips.
"""

import argparse
import hashlib
import json
import os
import pathlib
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time

REPO = pathlib.Path(__file__).resolve().parent.parent

FIXTURES = REPO / "tests" / "fixtures" / "manifests"
DATASET = (FIXTURES / "jobs-dataset.toml").read_text().replace("shard_size = 3", "shard_size = 4")

# The Indexed Job's dataset: two shards per index and slow enough samples (64², 16×32 light)
# that a pod can be killed between its shards.
INDEXED = DATASET.replace("shard_size = 4", "shard_size = 2").replace(
    "resolution = 16", "resolution = 64").replace('env_resolution = "4x8"', 'env_resolution = "16x32"')

TRAINING = (FIXTURES / "jobs-training.toml").read_text()


def fail(msg):
    print(f"test_k8s_jobs: FAILED: {msg}", file=sys.stderr)
    sys.exit(1)


def say(msg):
    print(f"test_k8s_jobs: {msg}", file=sys.stderr)


def exit_code(returncode):
    """A container's exit code as Kubernetes reports it (128 + signal for a signalled process)."""
    return 128 - returncode if returncode < 0 else returncode


def judged(policy, container, code):
    """The action of the first podFailurePolicy rule that matches an exit code (None: count it)."""
    for rule in (policy or {}).get("rules", []):
        on = rule.get("onExitCodes")
        if not on or on.get("containerName", container) != container:
            continue
        values = on["values"]
        hit = code in values if on["operator"] == "In" else code not in values
        if hit:
            return rule["action"]
    return None


def digest(folder):
    """Every file of a dataset but logs and locks, with its hash."""
    out = []
    for p in sorted(pathlib.Path(folder).rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_file() and not rel.startswith("logs/") and ".lock" not in p.name:
            out.append((rel, hashlib.sha256(p.read_bytes()).hexdigest()))
    return out


def mapped(arg, paths):
    """A container argument with the image's and the volume's paths mapped onto the test's, in
    one pass (a mapped path may contain another's prefix)."""
    table = dict(paths)
    keys = sorted(table, key=len, reverse=True)
    return re.sub("|".join(map(re.escape, keys)), lambda m: table[m.group(0)], arg)


def teardown(proc):
    """What ending a container does: every process in it is killed (its session here)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def wait_for_lines(path, n, proc, what):
    deadline = time.time() + 600
    while time.time() < deadline:
        if path.exists() and len(path.read_text().splitlines()) >= n:
            return
        if proc.poll() is not None:
            fail(f"{what} ended (exit {proc.returncode}) before {path} had {n} lines")
        time.sleep(0.05)
    fail(f"{what}: {path} never reached {n} lines")


def validate(docs):
    import kubernetes_validate
    from kubernetes_validate import utils

    version = utils.latest_version()
    for name, doc in docs.items():
        try:
            kubernetes_validate.validate(doc, version, strict=True)
        except Exception as e:  # the package raises several types
            fail(f"{name} is not a valid Kubernetes {version} object: {str(e).splitlines()[0]}")
        say(f"{name}: valid against Kubernetes {version}'s schema (strict)")


def training_job(job, trainer, root):
    spec = job["spec"]
    pod = spec["template"]["spec"]
    (container,) = pod["containers"]
    command = container["command"]
    if pathlib.PurePath(command[0]).name != "trainer" or command[1] != "run" or "--resume" not in command:
        fail(f"the training container's command is not `trainer run ... --resume`: {command}")
    (mount,) = container["volumeMounts"]
    volume = root / "volume"
    volume.mkdir()
    image_manifest = command[2]
    manifest = root / "train.toml"
    manifest.write_text(TRAINING.replace("@DATASET@", str(root / "data")))
    paths = [(image_manifest, str(manifest)), (mount["mountPath"], str(volume))]
    argv = [str(trainer)] + [mapped(a, paths) for a in command[1:]]
    out = pathlib.Path(argv[argv.index("--out") + 1])
    env = dict(os.environ)
    env.update({e["name"]: e["value"] for e in container.get("env", [])})
    # The manifest's interval is a minute; the test's pods live seconds.
    env["MATEDIT_PROGRESS_SECS"] = "1"
    grace = pod.get("terminationGracePeriodSeconds", 30)

    reference = root / "train-ref"
    r = subprocess.run([str(trainer), "run", str(manifest), "--out", str(reference), "--quiet"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"the uninterrupted training run failed: {r.stderr[-500:]}")

    # What happens to each pod: a signal after so many metric lines, or nothing.
    plan = [(signal.SIGTERM, 40), (signal.SIGKILL, 120), (signal.SIGTERM, 200), (None, None)]
    counted, pods = 0, 0
    metrics = out / "metrics.jsonl"
    for sig, after in plan:
        pods += 1
        log = root / f"train-pod-{pods}.log"
        with open(log, "w") as f:
            proc = subprocess.Popen(argv, env=env, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
            if sig is not None:
                wait_for_lines(metrics, after, proc, f"pod {pods}")
                sent = time.time()
                # The kubelet's SIGTERM goes to the container's first process; a kill, to all.
                if sig == signal.SIGKILL:
                    teardown(proc)
                else:
                    proc.send_signal(sig)
                try:
                    proc.wait(timeout=grace)
                except subprocess.TimeoutExpired:
                    teardown(proc)
                    fail(f"pod {pods} did not stop within terminationGracePeriodSeconds ({grace} s)")
                say(f"pod {pods}: {signal.Signals(sig).name} after {after} steps, stopped in "
                    f"{time.time() - sent:.1f} s, exit code {exit_code(proc.returncode)}")
            else:
                proc.wait()
            teardown(proc)
        code = exit_code(proc.returncode)
        if code == 0:
            break
        action = judged(spec.get("podFailurePolicy"), container["name"], code)
        if sig == signal.SIGTERM and action != "Ignore":
            fail(f"pod {pods} stopped by SIGTERM exited {code}, which the podFailurePolicy counts as a failure")
        if sig == signal.SIGKILL and action is not None:
            fail(f"pod {pods} was killed (exit {code}) and the podFailurePolicy {action}s it")
        if action == "FailJob":
            fail(f"pod {pods}: exit {code} fails the Job")
        if action is None:
            counted += 1
            if counted > spec.get("backoffLimit", 6):
                fail(f"the Job failed: {counted} counted failures > backoffLimit {spec.get('backoffLimit', 6)}")
    else:
        fail(f"the Job did not complete in {pods} pods")
    if counted != 1:
        fail(f"expected exactly the killed pod to count against backoffLimit, counted {counted}")
    if metrics.read_bytes() != (reference / "metrics.jsonl").read_bytes():
        fail("metrics.jsonl of the preempted Job differs from the uninterrupted run's")
    logs = "".join((root / f"train-pod-{k}.log").read_text() for k in range(1, pods + 1))
    if not re.search(r"steps: .*/s, .* elapsed", logs):
        fail("no plain progress line in the pods' logs")
    say(f"training Job: {pods} pods (2 preempted, 1 killed and counted, backoffLimit "
        f"{spec.get('backoffLimit')}), completed; metrics.jsonl identical to an uninterrupted run")


def check_fields(value, model, where):
    """`value` (YAML) against a model class of the operator's SDK: every key must be one of the
    model's fields, recursively for nested models; Kubernetes types are left to validate()."""
    import kubeflow.training.models as models
    names = {v: k for k, v in model.attribute_map.items()}
    for key, v in value.items():
        if key not in names:
            fail(f"{where}.{key}: not a field of {model.__name__} ({', '.join(sorted(names))})")
        kind = model.openapi_types[names[key]]
        m = re.fullmatch(r"dict\(str, (\w+)\)", kind)
        if m and hasattr(models, m.group(1)):
            for k, item in v.items():
                check_fields(item, getattr(models, m.group(1)), f"{where}.{key}.{k}")
        elif hasattr(models, kind):
            check_fields(v, getattr(models, kind), f"{where}.{key}")
        elif kind in ("int", "str", "bool") and not isinstance(v, {"int": int, "str": str, "bool": bool}[kind]):
            fail(f"{where}.{key}: {v!r} is not a {kind}")


def mpijob(job, mpi_trainer, root):
    """Checks the MPIJob and runs its launcher's command (see the module documentation)."""
    try:
        import kubeflow.training.models as models
    except ImportError as e:
        say(f"MPIJob skipped: {e} (pip install kubeflow-training)")
        return
    if (job.get("apiVersion"), job.get("kind")) != ("kubeflow.org/v1", "MPIJob"):
        fail("train_k8s_mpijob.yaml is not a kubeflow.org/v1 MPIJob")
    check_fields(job["spec"], models.KubeflowOrgV1MPIJobSpec, "spec")
    specs = job["spec"]["mpiReplicaSpecs"]
    if set(specs) != {"Launcher", "Worker"}:
        fail(f"mpiReplicaSpecs has {sorted(specs)}, not Launcher and Worker")
    validate({f"the MPIJob's {role} pod template": {"apiVersion": "v1", "kind": "PodTemplate",
                                                     "metadata": {"name": role.lower()},
                                                     "template": spec["template"]}
              for role, spec in specs.items()})
    launcher = specs["Launcher"]
    (container,) = launcher["template"]["spec"]["containers"]
    command = container["command"]
    if pathlib.PurePath(command[0]).name != "mpirun_preemptible.sh":
        fail(f"the launcher does not run scripts/mpirun_preemptible.sh: {command}")
    np_ = int(command[command.index("-np") + 1])
    slots = specs["Worker"]["replicas"] * job["spec"].get("slotsPerWorker", 1)
    if np_ != slots:
        fail(f"mpirun starts {np_} ranks, the workers have {slots} slots")
    t = command.index("trainer")
    if command[t + 1] != "run" or "--resume" not in command:
        fail(f"the launcher's command does not run `trainer run ... --resume`: {command}")
    if mpi_trainer is None or not mpi_trainer.is_file() or shutil.which("mpirun") is None:
        say("MPIJob: fields and pod templates valid; its run skipped: no MPI trainer (--mpi-trainer) or mpirun")
        return
    (mount,) = container["volumeMounts"]
    volume = root / "mpi-volume"
    volume.mkdir()
    manifest = root / "train-mpi.toml"
    # 200 steps: within the rank tests' tolerance of one process (see scripts/test_slurm.sh).
    text = TRAINING.replace("@DATASET@", str(root / "data"))
    short = text.replace("steps = 150\nbatch_size = 4\nlearning_rate = [[0, 1e-4]]",
                         "steps = 50\nbatch_size = 4\nlearning_rate = [[0, 1e-4]]")
    if short == text:
        fail("the joint stage of tests/fixtures/manifests/jobs-training.toml was not shortened (did it change?)")
    manifest.write_text(short)
    ranks = 2
    paths = [(command[t + 2], str(manifest)), (mount["mountPath"], str(volume))]
    argv = ([str(REPO / "scripts" / "mpirun_preemptible.sh"), "-np", str(ranks)]
            + [mapped(a, paths) for a in command[3:t]] + [str(mpi_trainer)]
            + [mapped(a, paths) for a in command[t + 1:]])
    out = pathlib.Path(argv[argv.index("--out") + 1])
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
               OMPI_MCA_rmaps_base_oversubscribe="1", MATEDIT_PROGRESS_SECS="1")
    grace = launcher["template"]["spec"].get("terminationGracePeriodSeconds", 30)
    reference = root / "train-mpi-ref"
    r = subprocess.run([str(mpi_trainer), "run", str(manifest), "--out", str(reference), "--quiet"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"the one-process training run failed: {r.stderr[-500:]}")
    metrics = out / "metrics.jsonl"
    limit = job["spec"].get("runPolicy", {}).get("backoffLimit", 6)
    restarts = 0
    for what, after in [("SIGTERM to the launcher", 40), ("SIGKILL to rank 1", 120), (None, None)]:
        log = root / f"mpijob-launcher-{restarts + 1}.log"
        with open(log, "w") as f:
            proc = subprocess.Popen(argv, env=env, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
            if what is not None:
                wait_for_lines(metrics, after, proc, f"launcher {restarts + 1}")
                sent = time.time()
                if what.startswith("SIGTERM"):
                    proc.send_signal(signal.SIGTERM)
                else:
                    rank = next((p for p in pathlib.Path("/proc").iterdir() if p.name.isdigit()
                                 and str(out) in _read(p / "cmdline").decode(errors="replace")
                                 and b"OMPI_COMM_WORLD_RANK=1\0" in _read(p / "environ") + b"\0"), None)
                    if rank is None:
                        fail("rank 1's process was not found")
                    os.kill(int(rank.name), signal.SIGKILL)
                try:
                    proc.wait(timeout=grace)
                except subprocess.TimeoutExpired:
                    teardown(proc)
                    fail(f"the launcher did not stop within {grace} s after {what}")
                say(f"MPIJob launcher {restarts + 1}: {what} after {after} steps, stopped in "
                    f"{time.time() - sent:.1f} s, exit code {exit_code(proc.returncode)}")
            else:
                try:
                    proc.wait(timeout=600)
                except subprocess.TimeoutExpired:
                    teardown(proc)
                    fail(f"the last launcher did not finish within 10 minutes (hung ranks?): {log}")
            teardown(proc)
        code = exit_code(proc.returncode)
        if what is not None and what.startswith("SIGTERM") and code != 75:
            fail(f"the launcher exited {code} after SIGTERM, not 75 (checkpoint written): {log.read_text()[-800:]}")
        if code == 0:
            break
        restarts += 1
        if restarts > limit:
            fail(f"the MPIJob failed: {restarts} restarts > runPolicy.backoffLimit {limit}")
    else:
        fail("the MPIJob did not complete")
    for name in out.joinpath("checkpoints").iterdir():
        if name.name.startswith(".") or "tmp" in name.name:
            fail(f"a partial checkpoint was left: {name}")
    a = [json.loads(l) for l in (reference / "metrics.jsonl").read_text().splitlines()]
    b = [json.loads(l) for l in metrics.read_text().splitlines()]
    if len(a) != len(b):
        fail(f"the MPIJob logged {len(b)} steps, one process {len(a)}")
    worst = 0.0
    for x, y in zip(a, b):
        if (x["stage"], x["step"]) != (y["stage"], y["step"]):
            fail(f"line {x['global_step']}: {x['stage']}/{x['step']} (one process) against {y['stage']}/{y['step']}")
        for k, v in x["losses"].items():
            w = y["losses"][k]
            d = abs(v - w) / max(abs(v), abs(w), 1e-30)
            if d > 1e-4 and abs(v - w) > 1e-9:
                fail(f"{k} at {x['stage']}/{x['step']}: {v} (one process) against {w} ({ranks} ranks)")
            worst = max(worst, d)
    say(f"MPIJob: {ranks} ranks, preempted and a rank killed, {restarts} restarts (backoffLimit {limit}), "
        f"completed; {len(b)} steps equal to one process (worst relative difference {worst:.1e})")


def _read(path):
    """A /proc file, or nothing where its process has gone."""
    try:
        return path.read_bytes()
    except OSError:
        return b""


def datagen_job(job, datagen, root):
    spec = job["spec"]
    if spec.get("completionMode") != "Indexed":
        fail("the datagen Job is not an Indexed Job")
    (container,) = spec["template"]["spec"]["containers"]
    script = " ".join(container.get("args", []))
    m = re.search(r"--worker\s+\"?\$\{JOB_COMPLETION_INDEX\}/(\d+)\"?", script)
    if not m:
        fail(f"the datagen command does not pass --worker \"${{JOB_COMPLETION_INDEX}}/N\": {script}")
    if int(m.group(1)) != spec["completions"]:
        fail(f"the command's worker count {m.group(1)} is not the Job's completions {spec['completions']}")
    words = shlex.split(script)
    image_manifest = words[words.index("run") + 1]
    (mount,) = container["volumeMounts"]
    manifest = root / "data-k8s.toml"
    manifest.write_text(INDEXED)
    r = subprocess.run([str(datagen), "run", str(manifest), "--out", str(root / "indexed-ref")],
                       capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"the single-process dataset: {r.stderr[-500:]}")
    n = 4

    def on_volume(name):
        """The pods' shell command with the volume at `root/name`, and the output folder."""
        volume = root / name
        volume.mkdir()
        paths = [(image_manifest, str(manifest)), (mount["mountPath"], str(volume)),
                 ("datagen ", f"{shlex.quote(str(datagen))} "), (f"}}/{m.group(1)}", f"}}/{n}")]
        sh = mapped(script, paths)
        return sh, pathlib.Path(re.search(r"--out\s+(\S+)", sh).group(1))

    def joined_equals_reference(out, what):
        for verb in ("join", "verify"):
            r = subprocess.run([str(datagen), verb, str(out)], capture_output=True, text=True)
            if r.returncode != 0:
                fail(f"{what}: datagen {verb}: {r.stderr[-500:]}")
        if digest(out) != digest(root / "indexed-ref"):
            fail(f"{what}: the joined dataset differs from the single-process run")

    def start(sh, index):
        env = dict(os.environ, JOB_COMPLETION_INDEX=str(index))
        env.update({e["name"]: e["value"] for e in container.get("env", [])})
        log = open(root / f"datagen-{index}.log", "a")
        return subprocess.Popen(container["command"] + [sh], env=env, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)

    # All indices at once, as the Job's parallelism runs them.
    sh, out = on_volume("dg-volume-parallel")
    pods = [start(sh, index) for index in range(min(n, spec.get("parallelism", 1)))]
    for index, proc in enumerate(pods):
        proc.wait()
        teardown(proc)
        if proc.returncode != 0:
            fail(f"index {index} of the parallel run exited {exit_code(proc.returncode)}")
    joined_equals_reference(out, "all indices at once")

    # One index at a time, index 2 killed between its shards and retried.
    sh, out = on_volume("dg-volume")
    limit = spec.get("backoffLimitPerIndex")
    if limit is None or limit < 1:
        fail("the datagen Job retries no index (backoffLimitPerIndex)")

    def pod(index, kill=False):
        proc = start(sh, index)
        if kill:
            # Killed once it has completed one shard of its own, before the next.
            done = len(list(out.glob("shards/*/shard.json")))
            while proc.poll() is None and len(list(out.glob("shards/*/shard.json"))) == done:
                time.sleep(0.001)
            teardown(proc)
        proc.wait()
        teardown(proc)
        return exit_code(proc.returncode)

    failures = {}
    for index in range(n):
        code = pod(index, kill=index == 2)
        while code != 0:
            failures[index] = failures.get(index, 0) + 1
            if failures[index] > limit:
                fail(f"index {index} failed {failures[index]} times > backoffLimitPerIndex {limit}")
            code = pod(index)
    if failures != {2: 1}:
        fail(f"expected index 2 to fail once and be retried, got {failures}")
    joined_equals_reference(out, "index 2 killed and retried")
    say(f"datagen Indexed Job: {n} indices all at once, and one at a time with index 2 killed after its "
        "first shard and retried: both joined datasets byte-identical to a single-process run")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trainer", default=REPO / "target/release/trainer", type=pathlib.Path)
    ap.add_argument("--datagen", default=REPO / "target/release/datagen", type=pathlib.Path)
    ap.add_argument("--mpi-trainer", default=REPO / "target/mpi/trainer", type=pathlib.Path,
                    help="a trainer built with --features mpi, for the MPIJob")
    ap.add_argument("--keep", action="store_true", help="keep the temporary folder")
    a = ap.parse_args()
    try:
        import yaml
        import kubernetes_validate  # noqa: F401
    except ImportError as e:
        say(f"skipped: {e} (pip install kubernetes-validate)")
        return
    for b in (a.trainer, a.datagen):
        if not b.is_file():
            fail(f"{b} does not exist: build it with cargo build --release --workspace")
    docs = {name: yaml.safe_load((REPO / "scripts" / name).read_text())
            for name in ("train_k8s_job.yaml", "datagen_k8s_job.yaml")}
    validate(docs)
    mpi = yaml.safe_load((REPO / "scripts" / "train_k8s_mpijob.yaml").read_text())
    root = pathlib.Path(tempfile.mkdtemp(prefix="matedit-k8s."))
    try:
        (root / "data.toml").write_text(DATASET)
        r = subprocess.run([str(a.datagen), "run", str(root / "data.toml"), "--out", str(root / "data")],
                           capture_output=True, text=True)
        if r.returncode != 0:
            fail(f"the single-process dataset: {r.stderr[-500:]}")
        datagen_job(docs["datagen_k8s_job.yaml"], a.datagen.resolve(), root)
        training_job(docs["train_k8s_job.yaml"], a.trainer.resolve(), root)
        mpijob(mpi, a.mpi_trainer.resolve() if a.mpi_trainer.is_file() else None, root)
    finally:
        if a.keep:
            say(f"kept {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
