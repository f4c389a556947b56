"""The module panel's state without Qt: the volume it shows, that volume's design, the Detail shown, whether the 3D
view was changed outside the module, and how these follow the scene (imports, closes) and the user (Apply, edits).

The widget (``IsoSimilarityTF.py``) gives a :class:`PanelView` that draws with Qt and its parameter node wrapper; the
model observes the scene and the parameter node itself with plain VTK observers, so the tests drive it on a real
``slicer-core`` scene with the events in Slicer's own order (``Testing/test_panel.py``).
"""

from typing import Callable, Optional

from . import mrml
from .errors import OptionError
from .options import check_options
from .session import AUTO_DETAIL, Cancelled, DesignSession

#: What :meth:`PanelModel.poll_job` says of the job: still running, done (its design shown), or its volume was
#: removed from the scene meanwhile (nothing shown).
JOB_RUNNING, JOB_DONE, JOB_VOLUME_REMOVED = "running", "done", "volume-removed"

#: The panel's parameters (the module's parameter node) and the engine options they set
#: (``design_transfer_function`` keywords); the parameter node takes each one's range, words and default from the
#: options table (``IsoSimilarityTF.py``).
PANEL_OPTIONS = {
    "bins": "n_bins",
    "levels": "levels",
    "crossing": "crossing",
    "normalization": "normalization",
    "preference": "preference",
    "damping": "damping",
    "maxIterations": "max_iter",
    "convergenceIterations": "convergence_iter",
    "maxClasses": "max_classes",
    "background": "background",
    "unconverged": "unconverged",
    "tissues": "tissues",
    "colors": "colors",
    "modality": "modality",
    "gradientOpacity": "gradient_opacity",
}
#: Parameter values that stand for the engine's None: all octree levels, a kind of volume detected from the data.
PANEL_NONE = {"levels": 0, "modality": "auto"}
#: The preference word for "the number in preferenceValue".
PREFERENCE_NUMBER = "number"


def engine_options(parameters) -> dict:
    """The engine's options from the panel's parameters, checked against the options table (once, here: a bad value
    raises :class:`~.errors.OptionError` before anything starts).

    ``tissues`` stays the panel's Detail (an int; the session maps it to a grouping once the classes are known).
    """
    options = {}
    for parameter, option in PANEL_OPTIONS.items():
        value = getattr(parameters, parameter)
        if parameter == "preference" and value == PREFERENCE_NUMBER:
            value = parameters.preferenceValue
        elif parameter in PANEL_NONE and value == PANEL_NONE[parameter]:
            value = None
        options[option] = value
    detail = options.pop("tissues")
    if isinstance(detail, bool) or not isinstance(detail, int) or detail < AUTO_DETAIL:
        raise OptionError(f"the Detail must be {AUTO_DETAIL} (automatic) or a number of tissues; got {detail!r}")
    checked = check_options(options)
    return {**{option: checked[option] for option in options}, "tissues": detail}


# vtkCommand::ModifiedEvent (the parameter node's), without importing VTK here.
_MODIFIED_EVENT = "ModifiedEvent"


def gui_tag(wrapper, tag):
    """The tag ``connectGui`` returned; on Slicer 5.8, whose ``connectGui`` returns None (``wrapper.py:241-253`` at
    v5.8.1; fixed in 5.10.0), the newest key of the wrapper's connector table (``:204-206``), so that
    ``disconnectGui`` undoes the connection there too. Otherwise the old connectors stay connected, and the next
    connection's rebuilt combo boxes make them write their first choice into the parameter node."""
    if tag is None:
        connected = getattr(wrapper, "_parameterGUIs", None)
        if connected:
            return max(connected)
    return tag


class PanelView:
    """What the model asks the panel to draw or ask; the widget overrides these with Qt (here they do nothing)."""

    def show_parameters(self) -> None:
        """The parameter node changed: enable what depends on it (Apply needs a volume, ...)."""

    def show_design(self, design) -> None:
        """Show a design, or none: the tree, the Detail slider's range, the similarity picture, the buttons."""

    def show_tree(self, design) -> None:
        """Rebuild the tree only (the grouping changed)."""

    def show_rows(self) -> None:
        """Set the tree's editors from the design (an edit was made or refused)."""

    def show_detail_label(self) -> None:
        """The text beside the Detail slider."""

    def show_outside_change(self, change: str) -> None:
        """Say that the 3D view shows another transfer function than the design (see :func:`.mrml.outside_change`)."""

    def confirm_overwrite(self, change: str) -> bool:
        """Ask before an edit replaces a transfer function changed outside the module."""
        return True

    def attempt(self, what: str, action: Callable[[], None]) -> None:
        """Run an action of the user's, showing its error (``what``: "regroup" or "edit")."""
        action()


class PanelModel:
    """The panel's state; one per widget.

    Args:
        session: the module's logic (a :class:`~.session.DesignSession`).
        view: the panel's drawing (:class:`PanelView`).
    """

    def __init__(self, session: DesignSession, view: PanelView) -> None:
        self.session = session
        self.view = view
        #: The parameter node wrapper (attributes ``inputVolume`` and ``tissues``), None when disconnected.
        self.parameters = None
        #: The volume whose design the panel shows (None: none).
        self.shown_volume = None
        #: The Detail the shown design is grouped with (None: no design shown; the Detail is then left alone).
        self.detail_shown: Optional[int] = None
        #: The design being computed in a child process (:class:`~.worker.DesignProcess`) and its volume.
        self.job = None
        self.job_volume = None
        #: A design is being computed in this process; Cancel was pressed meanwhile.
        self.in_process = False
        self.cancel_requested = False
        #: The input follows the scene's active volume (the selection node's) until the user picks another volume.
        self.follow_active_volume = True
        self._scene = None
        self._observations = []
        self._parameter_observation = None
        self._selection_node = None
        self._selection_observation = None

    @property
    def running(self) -> bool:
        """An Apply is under way: the panel then ignores the parameter node and the active volume until it ends."""
        return self.job is not None or self.in_process

    # Connections ---------------------------------------------------------------------------------------------------
    def observe_scene(self, scene) -> None:
        """Follow the scene's closes and imports (once; :meth:`stop` undoes it)."""
        self._scene = scene
        self._observe(scene, scene.StartCloseEvent, self.on_scene_start_close)
        self._observe(scene, scene.EndCloseEvent, self.on_scene_end_close)
        self._observe(scene, scene.EndImportEvent, self.on_scene_end_import)

    def observe_selection(self, selection_node) -> None:
        """Follow the active volume of this selection node (the application logic's; again after a scene close, in
        case it is another node)."""
        if selection_node is self._selection_node:
            return
        if self._selection_observation is not None:
            self._selection_node.RemoveObserver(self._selection_observation)
            self._selection_observation = None
        self._selection_node = selection_node
        if selection_node is not None:
            self._selection_observation = selection_node.AddObserver(_MODIFIED_EVENT, self._on_selection_modified)

    def set_parameters(self, parameters, node=None) -> None:
        """Follow a parameter node (``node``: the object whose ModifiedEvent to observe, by default the wrapper's
        ``parameterNode``), or none."""
        if self._parameter_observation is not None:
            self._parameter_observation[0].RemoveObserver(self._parameter_observation[1])
            self._parameter_observation = None
        self.parameters = parameters
        if parameters is not None:
            observed = parameters.parameterNode if node is None else node
            self._parameter_observation = (observed, observed.AddObserver(_MODIFIED_EVENT, self._on_modified))

    def stop(self) -> None:
        """Remove every observer (the widget is cleaned up)."""
        self.set_parameters(None)
        self.observe_selection(None)
        for observed, tag in self._observations:
            observed.RemoveObserver(tag)
        self._observations = []

    def _on_modified(self, caller, event) -> None:
        self.refresh()

    def _observe(self, observed, event, method) -> None:
        self._observations.append((observed, observed.AddObserver(event, lambda caller, event: method())))

    # The active volume -------------------------------------------------------------------------------------------
    def active_volume(self):
        """The scene's active volume if it is a plain scalar volume (the kind the selector lists), else None."""
        node_id = self._selection_node.GetActiveVolumeID() if self._selection_node is not None else None
        node = self._scene.GetNodeByID(node_id) if node_id and self._scene is not None else None
        return node if node is not None and node.GetClassName() == "vtkMRMLScalarVolumeNode" else None

    def select_active_volume(self) -> None:
        """The module is entered: select the active volume if the input follows it or nothing is selected."""
        active = self.active_volume()
        if active is not None and self.parameters is not None:
            if self.follow_active_volume or self.parameters.inputVolume is None:
                self.parameters.inputVolume = active

    def volume_picked(self, node) -> None:
        """The user picked a volume in the selector: the input follows the active volume again only if they picked
        it (or none)."""
        active = self.active_volume()
        self.follow_active_volume = node is None or active is None or node is active

    def _on_selection_modified(self, caller, event) -> None:
        if not self.follow_active_volume or self.parameters is None or self.running:
            return
        active = self.active_volume()
        if active is not None and active is not self.parameters.inputVolume:
            self.parameters.inputVolume = active

    # Following the scene -----------------------------------------------------------------------------------------
    def refresh(self) -> None:
        """The parameter node changed (the user, a script, or a scene import or close): show the selected volume's
        design if it is another volume, and regroup the shown design if the Detail changed."""
        if self.running or self.parameters is None:
            return
        self.view.show_parameters()
        # During an import the design's text node may not be added yet, or added with its .txt file not yet read
        # (vtkMRMLScene::Import reads storable nodes only after adding every node): wait for EndImport.
        if self._scene is not None and self._scene.IsImporting():
            return
        volume = self.parameters.inputVolume
        if volume is not self.shown_volume:
            self.show_volume(volume)
        self.detail_changed()

    def show_volume(self, volume) -> None:
        """Show the design stored for the volume (an earlier run, a saved scene), or none."""
        self.show_result(volume, self.session.restore(volume))
        change = self.session.outside_change()
        if change is not None:
            self.view.show_outside_change(change)

    def on_scene_end_import(self) -> None:
        """A scene was added or loaded: its nodes and files are all read now, so look at the volume again."""
        if self.parameters is not None and not self.running:
            self.show_volume(self.parameters.inputVolume)  # its show_result draws the Detail label

    def on_scene_start_close(self) -> None:
        self.session.forget()
        self.shown_volume = None
        self.detail_shown = None
        self.view.show_design(None)

    def on_scene_end_close(self) -> None:
        self.follow_active_volume = True

    # The Detail --------------------------------------------------------------------------------------------------
    def detail_changed(self) -> None:
        """Regroup the shown design when the parameter node's Detail is not the one it is grouped with."""
        detail = self.parameters.tissues
        if not self.shows_session_design() or detail == self.detail_shown:
            self.view.show_detail_label()
            return
        self.detail_shown = detail
        if self._confirm():
            self.view.attempt("regroup", lambda: self.session.regroup(detail))
        # The design's own setting: a count past its classes becomes its class count; if the user kept the other
        # transfer function, the Detail goes back to the design's grouping.
        self.detail_shown = self.session.detail()
        self.parameters.tissues = self.detail_shown
        self.view.show_tree(self.session.design)
        self.view.show_detail_label()

    def shows_session_design(self) -> bool:
        """Whether the panel shows the session's current design: the Detail and the edits act on it only (a script
        may have applied a design to another volume behind the panel)."""
        return (
            self.session.design is not None
            and self.detail_shown is not None
            and self.session.volume_node is self.shown_volume
        )

    def detail_design(self):
        """The design the Detail label describes (None when the panel shows none)."""
        return self.session.design if self.shows_session_design() else None

    def detail(self) -> int:
        return self.parameters.tissues if self.parameters is not None else AUTO_DETAIL

    # Apply -------------------------------------------------------------------------------------------------------
    def show_result(self, volume, design) -> None:
        """A design (or none) is the volume's: show it in the panel (after an Apply, or a restore)."""
        self.shown_volume = volume
        self.detail_shown = self.session.detail()
        # The slider's range first: it must not clamp the grouping written next.
        self.view.show_design(design)
        if design is not None and self.parameters is not None:
            self.parameters.tissues = self.detail_shown
        self.view.show_detail_label()

    def run_here(self, volume, options: dict, progress: Callable[[str, float, str], None]):
        """Design in this process and show the design. ``progress(stage, fraction, message)`` draws each report and
        lets Cancel be pressed (:meth:`cancel`). Returns the design, or None when cancelled or when the volume left
        the scene meanwhile (nothing changed then)."""
        self.in_process = True
        self.cancel_requested = False

        def report(stage: str, fraction: float, message: str) -> None:
            progress(stage, fraction, message)
            if self.cancel_requested or volume.GetScene() is None:
                raise Cancelled()

        try:
            design = self.session.run(volume, options, progress=report)
        except Cancelled:
            return None
        finally:
            self.in_process = False
        self.show_result(volume, design)
        return design

    def start_job(self, volume, options: dict) -> None:
        """Start designing in a child process (the volume is written for it first); then :meth:`poll_job`."""
        self.cancel_requested = False
        self.job = self.session.start(volume, options)
        self.job_volume = volume

    def poll_job(self) -> tuple:
        """``(reports, state)``: the job's progress reports since the last call and :data:`JOB_RUNNING`,
        :data:`JOB_DONE` (its design is shown; the child's error is raised) or :data:`JOB_VOLUME_REMOVED`."""
        job = self.job
        finished = not job.running
        reports = job.poll()
        if not finished:
            return reports, JOB_RUNNING
        volume = self.job_volume
        self.job = self.job_volume = None
        if volume.GetScene() is None:
            job.close()
            return reports, JOB_VOLUME_REMOVED
        self.show_result(volume, self.session.finish(volume, job))
        return reports, JOB_DONE

    def cancel(self) -> None:
        """Cancel the Apply: a job's processes are ended now and its files removed; a design in this process stops
        at its next progress report."""
        self.cancel_requested = True
        if self.job is not None:
            self.job.close()
        self.job = self.job_volume = None

    # Edits -------------------------------------------------------------------------------------------------------
    def _confirm(self) -> bool:
        """Whether an edit may write the design into the 3D view; when the user agrees to replace a transfer function
        changed outside (a preset copied in, Shift, Synchronize), the design's shading and gradient opacity come back
        too (a preset's ``CopyContent`` replaced them)."""
        change = self.session.outside_change()
        if change is None:
            return True
        if not self.view.confirm_overwrite(change):
            return False
        if change == mrml.CHANGE_EDITED:
            self.session.restyle()
        return True

    def edit(self, action: Callable[[], None]) -> None:
        """One edit of the shown design (a session method that rewrites the transfer function), after asking."""
        if self.shows_session_design() and self._confirm():
            self.view.attempt("edit", action)
        self.view.show_rows()
