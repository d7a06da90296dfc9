"""Stages on a real dask cluster: a `dask scheduler` and `dask worker` processes on 127.0.0.1.

The stores must be byte-identical to a LocalCluster run (the session's ``grid_preprocessed``:
the same 12 GRID clips through the same stages on a LocalCluster), also when a worker is
SIGKILLed in the middle of ``landmarks`` (its tasks re-run on the surviving worker), and over
TLS with certificates (``cluster.security``)."""
import contextlib
import datetime
import ipaddress
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from pipeline.errors import LipsynthError
from pipeline.params import ClusterSecurity
from tests.conftest import ROOT, shared
from tests.helpers.stages import make_params, run_preprocessing

N_CLIPS = 12            # = grid_preprocessed: the LocalCluster reference


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tls_args(certs):
    return ["--tls-ca-file", str(certs["ca"]), "--tls-cert", str(certs["node_cert"]), "--tls-key", str(certs["node_key"])]


def client_security(certs):
    from distributed.security import Security
    return Security(tls_ca_file=str(certs["ca"]), tls_client_cert=str(certs["client_cert"]),
                    tls_client_key=str(certs["client_key"]), require_encryption=True)


class Cluster:
    """A scheduler and ``n`` workers (each `dask worker` = nanny + worker process, in its own
    process group so that one SIGKILL takes both)."""

    def __init__(self, folder: Path, n: int, certs=None):
        self.certs = certs
        port = free_port()
        self.address = f"{'tls' if certs else 'tcp'}://127.0.0.1:{port}"
        dask = str(Path(sys.executable).parent / "dask")
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        extra = tls_args(certs) if certs else []
        folder.mkdir(parents=True, exist_ok=True)
        self.logs = folder

        def start(args, name):
            return subprocess.Popen([dask, *args, *extra], cwd=folder, env=env, start_new_session=True,
                                    stdout=subprocess.DEVNULL, stderr=open(folder / f"{name}.log", "wb"))
        self.scheduler = start(["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"]
                               + (["--protocol", "tls"] if certs else []), "scheduler")
        self.workers = [start(["worker", self.address, "--host", "127.0.0.1", "--nthreads", "1", "--no-dashboard",
                               "--name", f"w{i}"], f"w{i}") for i in range(n)]
        with self.client() as c:
            c.wait_for_workers(n, timeout=90)

    def client(self):
        from distributed import Client
        return Client(self.address, timeout=60, security=client_security(self.certs) if self.certs else None)

    def kill(self, i):
        os.killpg(self.workers[i].pid, signal.SIGKILL)
        self.workers[i].wait(timeout=30)

    def close(self):
        for p in self.workers[::-1] + [self.scheduler]:
            if p.poll() is None:
                p.terminate()
        for p in self.workers + [self.scheduler]:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


@contextlib.contextmanager
def dask_cluster(folder, n=2, certs=None):
    c = Cluster(folder, n, certs)
    try:
        yield c
    finally:
        c.close()


def clips():
    return [str(c) for c in sorted(shared("grid_s1", "video").glob("*.mp4"))[:N_CLIPS]]


def store_files(store: Path) -> dict:
    """Every file of a zarr store (shards, zarr.json metadata) → its bytes, by relative path."""
    return {p.relative_to(store).as_posix(): p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()}


def assert_same_store(a: Path, b: Path):
    fa, fb = store_files(a), store_files(b)
    assert sorted(fa) == sorted(fb), f"{b.name}: files differ: only in reference {sorted(set(fa) - set(fb))[:5]}, " \
                                     f"only in this run {sorted(set(fb) - set(fa))[:5]}"
    differ = [k for k in fa if fa[k] != fb[k]]
    assert not differ, f"{b.name}: {len(differ)} of {len(fa)} files differ from the LocalCluster run, e.g. {differ[:5]}"
    assert any("/c/" in k for k in fa) and "zarr.json" in fa


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name or ".old-" in p.name)


@pytest.mark.slow
@pytest.mark.real
def test_stores_are_byte_identical_to_a_local_cluster_run(tmp_path, grid_preprocessed):
    with dask_cluster(tmp_path / "cluster") as cluster:
        params = make_params(tmp_path, clips(), cluster={"address": cluster.address})
        run_preprocessing(params, ("ingest", "landmarks"))
        with cluster.client() as c:
            assert len(c.scheduler_info()["workers"]) == 2
            done = c.run(lambda dask_worker: dask_worker.state.executed_count)
            assert all(n > 0 for n in done.values()), f"a worker ran no task: {done}"
    for name in ("ingest", "landmarks"):
        assert_same_store(grid_preprocessed / f"{name}.zarr", tmp_path / f"{name}.zarr")
    assert leftovers(tmp_path) == []


@pytest.mark.slow
@pytest.mark.real
def test_in_process_stores_are_byte_identical_to_a_local_cluster_run(tmp_path, grid_preprocessed):
    """``cluster.address: in-process`` (how ``speak`` ingests its one target) runs the same tasks here."""
    params = make_params(tmp_path, clips(), cluster={"address": "in-process"})
    run_preprocessing(params, ("ingest", "landmarks"))
    for name in ("ingest", "landmarks"):
        assert_same_store(grid_preprocessed / f"{name}.zarr", tmp_path / f"{name}.zarr")
    assert leftovers(tmp_path) == []


def scheduler_transitions(client, keys):
    """(key, start, finish) of every scheduler transition of ``keys`` so far."""
    keys = set(keys)
    return client.run_on_scheduler(
        lambda dask_scheduler: [(t[0], t[1], t[2]) for t in dask_scheduler.transition_log if t[0] in keys])


@pytest.mark.slow
@pytest.mark.real
def test_a_worker_killed_in_the_middle_of_landmarks(tmp_path, grid_preprocessed):
    """SIGKILL one of two workers (nanny and worker process) once landmark shards are being
    written and it is running a task: the stage finishes on the survivor and its store is
    byte-identical — no shard half-written, missing or duplicated, no stray file."""
    ingest = tmp_path / "ingest.zarr"
    shutil.copytree(grid_preprocessed / "ingest.zarr", ingest)
    out = tmp_path / "landmarks.zarr"
    n_tasks = len(list((grid_preprocessed / "landmarks.zarr" / "valid" / "c").iterdir()))
    assert n_tasks >= 10                                  # one shard per clip: time to kill in between
    with dask_cluster(tmp_path / "cluster") as cluster, cluster.client() as watch, ThreadPoolExecutor(1) as pool:
        params = make_params(tmp_path, clips(), cluster={"address": cluster.address})
        stage = pool.submit(run_preprocessing, params, ("landmarks",))
        name_of = {}
        killed_keys, written = None, 0
        deadline = time.monotonic() + 600
        while killed_keys is None and not stage.done() and time.monotonic() < deadline:
            tmp = next(iter(tmp_path.glob(".landmarks.zarr.tmp-*")), None)
            written = len(list((tmp / "valid" / "c").glob("*"))) if tmp and (tmp / "valid" / "c").exists() else 0
            if written:
                if not name_of:
                    name_of = {a: w["name"] for a, w in watch.scheduler_info()["workers"].items()}
                busy = {name_of.get(a): keys for a, keys in watch.processing().items()}
                if busy.get("w1"):
                    cluster.kill(1)                       # mid-stage: shards written, w1 running a task
                    killed_keys = list(busy["w1"])
                    break
            time.sleep(0.01)
        assert killed_keys, f"landmarks finished (or timed out) before w1 could be killed mid-stage ({written} shards)"
        assert not stage.done() and written < n_tasks
        stage.result(timeout=600)                         # the stage still finishes
        assert [w["name"] for w in watch.scheduler_info()["workers"].values()] == ["w0"]
        log = scheduler_transitions(watch, killed_keys)
        for key in killed_keys:                            # w1's task ran again, on w0
            went = [finish for k, _, finish in log if k == key]
            assert went.count("processing") >= 2 and "memory" in went, (key, went)
    assert_same_store(grid_preprocessed / "landmarks.zarr", out)
    assert leftovers(tmp_path) == []


# --- TLS ------------------------------------------------------------------------------------------

def make_certs(folder: Path, ca_name="lipsynth test CA") -> dict:
    """A throwaway CA and two certificates it signed (nodes: scheduler and workers; the client)."""
    pytest.importorskip("cryptography", reason="cryptography (installed with dvc, via scmrepo → asyncssh) is absent")
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    folder.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, ca_name)])

    def cert(subject, key, issuer_key, issuer, ca):
        b = (x509.CertificateBuilder().subject_name(subject).issuer_name(issuer).public_key(key.public_key())
             .serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(hours=1)).not_valid_after(now + datetime.timedelta(days=1))
             .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True)
             .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
             .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(issuer_key.public_key()), critical=False))
        if ca:
            b = b.add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                              content_commitment=False, key_encipherment=False, data_encipherment=False,
                                              key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
        else:
            b = b.add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost"),
                                                             x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
                                critical=False)
        return b.sign(issuer_key, hashes.SHA256())

    def write(name, obj):
        path = folder / name
        if isinstance(obj, x509.Certificate):
            path.write_bytes(obj.public_bytes(serialization.Encoding.PEM))
        else:
            path.write_bytes(obj.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                               serialization.NoEncryption()))
            path.chmod(0o600)
        return path

    out = {"ca": write("ca.pem", cert(ca_subject, ca_key, ca_key, ca_subject, True))}
    for who in ("node", "client"):
        key = ec.generate_private_key(ec.SECP256R1())
        subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"lipsynth {who}")])
        out[f"{who}_cert"] = write(f"{who}.pem", cert(subject, key, ca_key, ca_subject, False))
        out[f"{who}_key"] = write(f"{who}.key", key)
    return out


def security_params(certs, require=True):
    return ClusterSecurity(tls_ca_file=str(certs["ca"]), tls_client_cert=str(certs["client_cert"]),
                           tls_client_key=str(certs["client_key"]), require_encryption=require)


def test_cluster_security_maps_onto_dask_security(tmp_path):
    from pipeline.io.parallel import security_for
    from pipeline.params import Cluster
    certs = make_certs(tmp_path)
    sec = security_for(Cluster(address="tls://10.0.0.5:8786", security=security_params(certs)))
    assert sec.tls_ca_file == str(certs["ca"]) and sec.tls_client_cert == str(certs["client_cert"])
    assert sec.tls_client_key == str(certs["client_key"]) and sec.require_encryption
    assert security_for(Cluster(address="tcp://10.0.0.5:8786")) is None
    assert security_for(Cluster(address=None, security=security_params(certs))) is None      # LocalCluster
    with pytest.raises(LipsynthError, match="not encrypted and cluster.security.require_encryption"):
        security_for(Cluster(address="tcp://10.0.0.5:8786", security=security_params(certs)))
    from pipeline.io import parallel                    # ... but a LocalCluster of this process (127.0.0.1) is fine:
    parallel._OWN_CLUSTERS.add("tcp://127.0.0.1:45678")  # lipsynth.target reconnects its stages to the one it started
    try:
        assert security_for(Cluster(address="tcp://127.0.0.1:45678", security=security_params(certs))) is None
    finally:
        parallel._OWN_CLUSTERS.discard("tcp://127.0.0.1:45678")
    with pytest.raises(LipsynthError, match="tls:// but no certificates"):
        security_for(Cluster(address="tls://10.0.0.5:8786"))
    with pytest.raises(LipsynthError, match=r"cluster.security.tls_client_key: .*missing.key not found"):
        security_for(Cluster(address="tls://10.0.0.5:8786", security=ClusterSecurity(
            tls_ca_file=str(certs["ca"]), tls_client_cert=str(certs["client_cert"]), tls_client_key="missing.key")))


@pytest.mark.slow
@pytest.mark.real
def test_a_stage_runs_over_tls_and_a_stranger_is_refused(tmp_path, grid_preprocessed):
    """`dask scheduler --protocol tls` and a worker with certificates of a throwaway CA; the stage
    connects with cluster.security. A client with another CA's certificate, or plain tcp, is refused."""
    from pipeline.io.parallel import client_for
    from pipeline.params import Cluster
    certs = make_certs(tmp_path / "certs")
    shutil.copytree(grid_preprocessed / "ingest.zarr", tmp_path / "ingest.zarr")
    with dask_cluster(tmp_path / "cluster", n=1, certs=certs) as cluster:
        assert cluster.address.startswith("tls://")
        params = make_params(tmp_path, clips(), cluster={"address": cluster.address, "security": security_params(certs)})
        run_preprocessing(params, ("landmarks",))
        with cluster.client() as c:
            done = c.run(lambda dask_worker: dask_worker.state.executed_count)
            assert list(done.values())[0] > 0
        stranger = make_certs(tmp_path / "stranger", ca_name="someone else's CA")
        for cluster_params in (Cluster(address=cluster.address, connect_timeout=3, security=security_params(stranger)),
                               Cluster(address=cluster.address.replace("tls://", "tcp://"), connect_timeout=3)):
            with pytest.raises(LipsynthError, match="cannot reach the dask scheduler"):
                with client_for(cluster_params):
                    pass
    assert_same_store(grid_preprocessed / "landmarks.zarr", tmp_path / "landmarks.zarr")
