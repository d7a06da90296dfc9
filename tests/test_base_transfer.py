"""bench/base_transfer.py's leave-one-person-out choice and bench/shipped_base.py's corpus subset (pure parts)."""
import numpy as np

from bench.base_transfer import leave_one_out
from bench.shipped_base import corpus_line, every_nth


def test_the_choice_for_a_person_never_looks_at_that_person():
    # candidate 1 is best on everyone but person 0, where only candidate 0 is good: person 0's pick must still
    # be candidate 1 (chosen on the others), and its held-out score candidate 1's poor one
    table = np.array([[0.9, 0.1, 0.1, 0.1],
                      [0.0, 0.5, 0.5, 0.5]])
    picks, held = leave_one_out(table)
    assert picks == [1, 1, 1, 1]
    assert held.tolist() == [0.0, 0.5, 0.5, 0.5]


def test_a_candidate_that_wins_only_by_one_person_is_not_chosen_for_the_others():
    table = np.array([[0.3, 0.3, 0.3, 0.3, 0.3],
                      [0.9, 0.2, 0.2, 0.2, 0.2]])      # its median over any four others is ≤ 0.2
    picks, held = leave_one_out(table)
    assert picks == [0] * 5 and np.allclose(held, 0.3)


def test_every_nth_links_the_sorted_clips_without_the_damaged_one(tmp_path):
    corpus = tmp_path / "video"
    corpus.mkdir()
    names = ["a1", "b2", "pbio7a", "c3", "d4", "e5", "f6", "g7"]
    for n in names:
        (corpus / f"{n}.mp4").write_bytes(b"x")
    folder = every_nth(corpus, 3, tmp_path / "every3")
    assert sorted(p.name for p in folder.iterdir()) == ["a1.mp4", "d4.mp4", "g7.mp4"]
    assert all(p.is_symlink() and p.resolve().parent == corpus for p in folder.iterdir())
    assert every_nth(corpus, 3, tmp_path / "every3") == folder                  # again: the same links, no error
    assert corpus_line(str(folder), ["obama=x/*.mp4"]).startswith("GRID s1 (3 clips")
    assert corpus_line(str(folder), ["obama=x/*.mp4"]).endswith("+ obama (x/*.mp4)")
