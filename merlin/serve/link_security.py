"""From the ``links:`` section of the configuration (and the command line) to each link's security policy.

A safety reviewer sets who may talk on the controller and ground-station links, and which messages must be
signed, in the same file as the envelope (``links:``, :class:`merlin.config.models.LinksConfig`). The
command line of ``merlin serve`` overrides it per setting: ``--signing-key FILE`` puts that key on both links
and requires signatures on both, ``--allow-unsigned-provisioning`` allows it on both, ``--controller-sysids``
and ``--gcs-sysids`` replace the system-id allow-lists.

Mapping onto :class:`merlin.link.security.LinkPolicy`: ``require_signed: true`` is the default signed set
(authority, commands, setpoints, fence uploads, parameter writes), even with no key loaded yet, so the link
fails closed until a key is provisioned; ``require_signed: false`` requires nothing, but a key still signs
what Merlin sends and a signature that does not verify is still rejected.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from merlin.config.models import LinkConfig, LinksConfig
from merlin.link.security import DEFAULT_SIGNED_CLASSES, LinkPolicy
from merlin.link.signing import KeyFileError, load_key_file


@dataclass(frozen=True, slots=True)
class LinkOverrides:
    """What the command line says about link security; None leaves the configuration's value."""

    key_file: Path | None = None  # both links; implies require_signed
    allow_unsigned_provisioning: bool | None = None  # both links
    controller_system_ids: frozenset[int] | None = None
    gcs_system_ids: frozenset[int] | None = None


@dataclass(frozen=True, slots=True)
class LinkSetup:
    """One link's policy and where a key provisioned with SETUP_SIGNING is written (None: kept in memory)."""

    policy: LinkPolicy
    key_file: Path | None


class KeyFileProblem(ValueError):
    """A key file named in the configuration or on the command line is missing or does not hold a key.
    ``where`` is the key path (``links.controller.signing.key_file``) or the option (``--signing-key``)."""

    def __init__(self, where: str, message: str) -> None:
        self.where = where
        super().__init__(f"{where}: {message}")


def _ids(values: list[int] | None) -> frozenset[int] | None:
    return None if values is None else frozenset(values)


def _setup(name: str, cfg: LinkConfig, config_dir: Path, ov: LinkOverrides,
           sysids_override: frozenset[int] | None) -> LinkSetup:
    sig = cfg.signing
    where = f"links.{name}.signing.key_file"
    key_path = (config_dir / sig.key_file) if sig.key_file is not None else None
    require = sig.require_signed
    if ov.key_file is not None:
        key_path, where, require = ov.key_file, "--signing-key", True
    allow_prov = sig.allow_unsigned_provisioning if ov.allow_unsigned_provisioning is None else (
        ov.allow_unsigned_provisioning)
    key = None
    if key_path is not None:
        if key_path.exists():
            try:
                key = load_key_file(key_path)
            except (KeyFileError, OSError) as exc:
                raise KeyFileProblem(where, str(exc)) from None
        elif not allow_prov:
            raise KeyFileProblem(where, f"{str(key_path)!r} does not exist (allowed: an existing key file, or "
                                        "no file with allow_unsigned_provisioning, which writes it)")
    policy = LinkPolicy(
        name=name,
        allowed_system_ids=sysids_override if sysids_override is not None else _ids(cfg.allowed_system_ids),
        allowed_component_ids=_ids(cfg.allowed_component_ids),
        signing_key=key,
        require_signed=DEFAULT_SIGNED_CLASSES if require else frozenset(),
        allow_unsigned_provisioning=allow_prov,
    )
    return LinkSetup(policy, key_path)


def link_setups(links: LinksConfig, config_dir: Path, overrides: LinkOverrides = LinkOverrides()
                ) -> dict[str, LinkSetup]:
    """The controller's and the ground station's :class:`LinkSetup`; relative key files are relative to
    ``config_dir`` (the configuration file's directory). Raises :class:`KeyFileProblem`."""
    return {
        "controller": _setup("controller", links.controller, config_dir, overrides, overrides.controller_system_ids),
        "gcs": _setup("gcs", links.gcs, config_dir, overrides, overrides.gcs_system_ids),
    }


def describe(setup: LinkSetup) -> dict[str, object]:
    """What the event log records about a link's security (never the key)."""
    p = setup.policy
    return {
        "signing_key": "loaded" if p.signing_key is not None else "none",
        "key_file": str(setup.key_file) if setup.key_file is not None else None,
        "require_signed": sorted(c.value for c in p.required_classes(p.signing_key is not None)),
        "allow_unsigned_provisioning": p.allow_unsigned_provisioning,
        "allowed_system_ids": sorted(p.allowed_system_ids) if p.allowed_system_ids is not None else None,
        "allowed_component_ids": sorted(p.allowed_component_ids) if p.allowed_component_ids is not None else None,
    }


__all__ = ["KeyFileProblem", "LinkOverrides", "LinkSetup", "describe", "link_setups"]
