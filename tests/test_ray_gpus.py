"""Ray GPU tasks (physhand_mj/distributed.py) pick the GPU Ray gave them themselves, so that a reused
worker process, whose Warp keeps the GPUs it saw first, cannot run on a GPU an earlier task was given:
Ray keeps CUDA_VISIBLE_DEVICES as the node has it (the switch) and the task maps its GPU to an
ordinal (task_device). The mapping is tested directly; the switch on a local Ray that declares 2
GPUs on this CPU machine (GPU tasks with device="cpu": the resource path without a CUDA device).
A reused worker on a real second GPU needs a 2-GPU machine (benchmarks/ray_scaling.py ran there)."""

import logging
import os

import pytest

from physhand_mj.distributed import NOSET_CUDA, task_device

ray = pytest.importorskip("ray")


@pytest.mark.parametrize("ids,visible,want", [
    ([0], None, "cuda:0"), ([1], None, "cuda:1"),
    (["3"], "2,3", "cuda:1"), (["2"], "2, 3", "cuda:0"),
    (["GPU-b"], "GPU-a,GPU-b", "cuda:1"),
])
def test_task_device_is_the_ordinal_of_the_gpu_ray_gave(ids, visible, want):
    assert task_device("cuda", ids, visible) == want


def test_task_device_keeps_cpu_tasks_and_takes_cuda_0_as_the_tasks_gpu():
    assert task_device("cuda:0", ["1"], "0,1") == "cuda:1"  # as when Ray narrowed the visible GPUs
    assert task_device("cpu", [0], None) == "cpu"
    assert task_device("cuda", [], None) == "cuda"  # no GPU from Ray (gpus_per_worker=0)
    assert task_device(None, [0], None) is None


def test_task_device_says_what_to_fix_for_a_gpu_it_cannot_see():
    with pytest.raises(ValueError, match="does not see"):
        task_device("cuda", ["5"], "0,1")
    with pytest.raises(ValueError, match="CUDA_VISIBLE_DEVICES"):
        task_device("cuda", ["GPU-x"], None)


@pytest.fixture(scope="module")
def two_gpu_ray():
    saved = {k: os.environ.pop(k, None) for k in ("CUDA_VISIBLE_DEVICES", NOSET_CUDA)}  # Ray's 2 GPUs: "0", "1"
    try:
        ray.init(num_cpus=2, num_gpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
        yield
        ray.shutdown()
    finally:
        os.environ.update({k: v for k, v in saved.items() if v is not None})


@pytest.mark.slow  # (a local Ray's start)
def test_gpu_tasks_keep_the_nodes_visible_gpus_and_get_distinct_ones(two_gpu_ray, tmp_path):
    def _probe(folder: str, tag: str):
        """A task that waits until both tasks of its pair run (each then holds a GPU of its own), and
        returns the CUDA_VISIBLE_DEVICES it sees and the GPU Ray gave it."""
        import time
        from pathlib import Path

        Path(folder, f"{tag}-{os.getpid()}-{time.monotonic_ns()}").touch()
        t = time.monotonic()
        while len(list(Path(folder).glob(f"{tag}-*"))) < 2 and time.monotonic() - t < 60:
            time.sleep(0.02)
        return os.environ.get("CUDA_VISIBLE_DEVICES"), [str(i) for i in ray.get_gpu_ids()]

    probe = ray.remote(_probe)  # (defined here: Ray ships it by value, the workers cannot import tests)
    opts = dict(num_cpus=1, num_gpus=1, runtime_env={"env_vars": {NOSET_CUDA: "1"}})
    got = ray.get([probe.options(**opts).remote(str(tmp_path), "noset") for _ in range(2)])
    assert [g[0] for g in got] == [None, None]  # Ray did not narrow the visible GPUs per task
    assert sorted(g[1][0] for g in got) == ["0", "1"]  # and each task holds its own
    plain = ray.get([probe.options(num_cpus=1, num_gpus=1).remote(str(tmp_path), "plain") for _ in range(2)])
    assert sorted(g[0] for g in plain) == ["0", "1"]  # without the switch Ray narrows it (the contrast)


@pytest.mark.slow  # (a local Ray's start)
def test_rollout_ray_refuses_a_numbered_gpu_for_gpu_tasks(two_gpu_ray, tmp_path):
    import physhand_mj as ph
    from physhand_mj.distributed import rollout_ray

    with pytest.raises(ValueError, match="the GPU Ray gives it"):
        rollout_ray([(ph.scene_path("hoi_apple"), "grasp")], tmp_path, gpus_per_worker=1, device="cuda:1",
                    steps=2, progress=False)


@pytest.mark.slow  # (a local Ray's start)
def test_rollout_ray_runs_gpu_tasks_with_the_switch(two_gpu_ray, tmp_path):
    import physhand_mj as ph
    from physhand_mj.distributed import rollout_ray

    apple = ph.scene_path("hoi_apple")
    rows = rollout_ray([(apple, "grasp"), (apple, "grasp")], tmp_path, gpus_per_worker=1, device="cpu",
                       steps=2, batch=1, progress=False)
    assert len(rows) == 2 and all(r["finite"] and not r.get("error") for r in rows)
    assert (tmp_path / "summary.csv").is_file()
