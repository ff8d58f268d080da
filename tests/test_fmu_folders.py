"""FMU files extracted once per process and content (orchestration/fmu_folders.py), and the master's use of them."""

import multiprocessing
import os
import shutil
import zipfile

from nfal.orchestration import fmu_folders
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
    assert (tmp_path / "a.fmu").read_bytes() != (tmp_path / "b.fmu").read_bytes()
    assert open(f"{other}/modelDescription.xml").read() == "two"


def test_a_forgotten_fmu_is_extracted_into_a_new_folder_and_the_old_one_stays(tmp_path):
    fmu = _fmu(tmp_path / "a.fmu", "forgotten")
    first = fmu_folders.extracted(fmu)
    fmu_folders.forget(fmu)
    again = fmu_folders.extracted(fmu)
    assert again != first and (tmp_path / first).is_dir()  # a library mapped from it is never unmapped


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
    assert child.exitcode == 0 and folders[0] == parent
    assert os.path.dirname(folders[1]) != os.path.dirname(parent)
    assert os.path.isdir(parent)  # the child's end removed no folder of its parent's


def test_a_second_run_instantiates_the_fmus_where_the_first_extracted_them(fig7_archives, tmp_path):
    folders = []
    for k in range(2):
        run_structure(fig7_archives["fig7_slow"], stop_time=0.002, out_dir=tmp_path / f"run{k}", plot=False)
        folders.append(set(fmu_folders._folders.values()))
    assert len(folders[0]) >= 5 and folders[1] == folders[0]
