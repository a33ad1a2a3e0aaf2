"""The papers the benchmark reports compare with, cited by authors, title, venue and year.

Reports name a paper in the text by :attr:`Reference.cite` (``Andreis et al. (2024)``) and list
the full entries under a ``## References`` heading (:func:`references_md`). The two 2023 papers
share a first author and a year, hence ``2023a`` / ``2023b`` (ordered by title).

>>> print(NAVIGATION.cite)
Andreis et al. (2024)
>>> references_md([NAVIGATION])[2].startswith("- Andreis, E., Panicucci, P., and Topputo, F. (2024).")
True
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Reference", "IMAGE_PROCESSING", "VALIDATION", "NAVIGATION", "references_md"]


@dataclass(frozen=True)
class Reference:
    """One paper: ``cite`` in running text, ``entry`` in the references list."""

    cite: str
    authors: str
    year: str
    title: str
    venue: str

    @property
    def entry(self) -> str:
        return f"{self.authors} ({self.year}). {self.title}. {self.venue}."


#: The image-processing pipeline: centroids, k-vector star ID, RANSAC + Wahba, beacon ellipse;
#: its Monte Carlo results are Tables 3 and 4.
IMAGE_PROCESSING = Reference(
    cite="Andreis et al. (2023a)",
    authors="Andreis, E., Panicucci, P., and Topputo, F.",
    year="2023a",
    title="An Image Processing Pipeline for Autonomous Deep-Space Optical Navigation",
    venue="arXiv preprint arXiv:2302.06918")

#: The rendering engine, the RETINA bench's calibration and the hardware-in-the-loop navigation
#: results (Figs. 7-8: position and velocity errors with their 3-sigma bounds).
VALIDATION = Reference(
    cite="Andreis et al. (2023b)",
    authors="Andreis, E., Panicucci, P., Ornati, F., and Topputo, F.",
    year="2023b",
    title="Towards Validation and Verification of Autonomous Vision-Based Navigation for Interplanetary Spacecraft",
    venue="12th International Conference on Guidance, Navigation & Control Systems (ESA GNC), Sopot, Poland")

#: The navigation filter: first-order light-time and aberration, measurement cases 1-5, the
#: Earth-Mars cruise results (final 3-sigma 1953 km, 0.41 m/s).
NAVIGATION = Reference(
    cite="Andreis et al. (2024)",
    authors="Andreis, E., Panicucci, P., and Topputo, F.",
    year="2024",
    title="Autonomous Vision-Based Algorithm for Interplanetary Navigation",
    venue="Journal of Guidance, Control, and Dynamics, doi:10.2514/1.G007926")


def references_md(refs) -> list:
    """Markdown lines of a ``## References`` section listing ``refs`` (in the given order)."""
    return ["## References", ""] + [f"- {r.entry}" for r in refs] + [""]
