"""FMU files extracted once per process and content (orchestration/fmu_folders.py), and the master's use of them."""

import multiprocessing
import os
import shutil
import zipfile

from nfal.orchestration import Master, fmu_folders, read_ssp, resolve
from nfal.orchestration.run import run_structure


def _fmu(path, text: str):
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", text)
    return path


def test_one_folder_per_content_wherever_the_file_is(tmp_path):
    first = fmu_folders.extracted(_fmu(tmp_path / "a.fmu", "one"))
    (tmp_path / "elsewhere").mkdir()
    copy = shutil.copy2(tmp_path / "a.fmu", tmp_path / "elsewhere" / "a.fmu")
    assert fmu_folders.extracted(copy) == first == fmu_folders.extracted(tmp_path / "a.fmu")
    other = fmu_folders.extracted(_fmu(tmp_path / "b.fmu", "two"))
    assert other != first
    assert open(f"{other}/modelDescription.xml").read() == "two"


def test_a_forgotten_fmu_is_extracted_into_a_new_folder_and_the_old_one_stays(tmp_path):
    fmu = _fmu(tmp_path / "a.fmu", "forgotten")
    first = fmu_folders.extracted(fmu)
    fmu_folders.forget(first)
    again = fmu_folders.extracted(fmu)
    assert again != first and os.path.isdir(first)  # a library loaded from it may still be in use


def _extract_in_child(fmus, queue):
    queue.put([fmu_folders.extracted(fmu) for fmu in fmus])


def test_a_forked_child_uses_its_parents_folders_and_extracts_into_its_own(tmp_path):
    inherited, new = _fmu(tmp_path / "a.fmu", "inherited"), _fmu(tmp_path / "b.fmu", "new in the child")
    parent = fmu_folders.extracted(inherited)
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_extract_in_child, args=([inherited, new], queue))
    child.start()
    folders = queue.get(timeout=60)
    child.join(timeout=60)
    shutil.rmtree(os.path.dirname(folders[1]))  # the child's own (it ends with os._exit: no exit handlers)
    assert child.exitcode == 0 and folders[0] == parent
    assert os.path.dirname(folders[1]) != os.path.dirname(parent)
    assert os.path.isdir(parent)  # the child's end removed no folder of its parent's


def test_a_second_run_extracts_nothing_and_gives_the_same_results(fig7_archives, tmp_path, monkeypatch):
    monkeypatch.setattr(fmu_folders, "_folders", {})  # as in a fresh process
    calls = []
    original = fmu_folders.extract
    monkeypatch.setattr(fmu_folders, "extract", lambda *args, **kwargs: calls.append(1) or original(*args, **kwargs))
    extractions = []
    for k in range(2):
        run_structure(fig7_archives["fig7_slow"], stop_time=0.02, out_dir=tmp_path / f"run{k}", plot=False)
        extractions.append(len(calls))
    assert extractions == [5, 5]  # the five FMUs of fig7_slow, in the first run only
    # the FMUs' modules, loaded once, hold no state from one run to the next
    assert (tmp_path / "run0" / "results.csv").read_bytes() == (tmp_path / "run1" / "results.csv").read_bytes()


def test_after_fmi2fatal_no_call_and_the_next_run_extracts_the_fmu_anew(fig7_archives, monkeypatch):
    monkeypatch.setattr(fmu_folders, "_folders", {})
    with read_ssp(fig7_archives["fig7_slow"]) as structure:
        master = Master(resolve(structure, {}), step_size=5e-4)
        master.instantiate()
        plant = master._slaves["Plant"]
        plant.state = "fatal"  # as a call that returned fmi2Fatal leaves it
        master.close()
        assert plant.state == "fatal"  # not freed: FMI allows no further call
        assert fmu_folders.extracted(plant.element.source) != plant.folder

