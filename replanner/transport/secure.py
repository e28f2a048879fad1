"""The secure profile: a certificate authority, one certificate per identity, and per identity a Zenoh config with
mutual TLS and access control (deny by default; each identity may only do its own part of the protocol).

Zenoh enforces the rules in every session on the messages that cross its links, matched by the certificate
common name of the other end. Peer to peer, every process enforces them; through a router, the router does (the
other sessions trust only the router's certificate for what it forwards). docs/security.md has the threat model.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError
from .keys import SIM_KEYS, Keys

# identity -> the parts of the protocol it plays; `sim` is the simulated cell: robot, cameras and the sim's own keys
ROLES = ("service", "robot", "sensor", "sim", "client", "router")
DEFAULT_IDENTITIES = {
    "service": "service",
    "robot": "robot",
    "camera": "sensor",
    "sim": "sim",
    "operator": "client",
    "router": "router",
}
ALL_MESSAGES = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
]
_NAME_CHARS = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_")


@dataclass(frozen=True)
class Identity:
    name: str  # the certificate's common name
    role: str


def parse_identities(specs: list[str]) -> list[Identity]:
    """`name:role` pairs (e.g. `picker:client`); an unknown role or a malformed name is named."""
    out = []
    for spec in specs:
        name, sep, role = spec.partition(":")
        if not sep or not name or not set(name) <= _NAME_CHARS or role not in ROLES:
            raise ConfigError(
                f"--identity {spec!r}: write NAME:ROLE with NAME of letters, digits, '-' or '_' and ROLE one of "
                f"{', '.join(ROLES)}"
            )
        out.append(Identity(name, role))
    return out


def make_certificates(out: Path, identities: list[Identity], hosts: list[str] = (), days: int = 365) -> dict[str, Path]:
    """A CA (ca.pem, ca.key) and per identity NAME.pem / NAME.key signed by it, valid for `days`; an existing CA in
    `out` is reused so identities can be added later. SANs: localhost, 127.0.0.1, the name and `hosts`."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    out.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc) - datetime.timedelta(minutes=5)
    later = now + datetime.timedelta(days=days)

    def write_key(key, path: Path) -> None:
        path.write_bytes(
            key.private_bytes(
                serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
            )
        )
        path.chmod(0o600)

    ca_pem, ca_key_path = out / "ca.pem", out / "ca.key"
    if ca_pem.exists() and ca_key_path.exists():
        ca_cert = x509.load_pem_x509_certificate(ca_pem.read_bytes())
        ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), None)
    else:
        ca_key = ec.generate_private_key(ec.SECP256R1())
        ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "replanner cell CA")])
        ca_cert = (
            x509.CertificateBuilder()
            .subject_name(ca_name)
            .issuer_name(ca_name)
            .public_key(ca_key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now)
            .not_valid_after(now + datetime.timedelta(days=max(days, 3650)))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True)
            .sign(ca_key, hashes.SHA256())
        )
        write_key(ca_key, ca_key_path)
        ca_pem.write_bytes(ca_cert.public_bytes(serialization.Encoding.PEM))
    written = {"ca": ca_pem}
    for ident in identities:
        key = ec.generate_private_key(ec.SECP256R1())
        sans: list[x509.GeneralName] = [x509.DNSName("localhost"), x509.DNSName(ident.name)]
        sans.append(x509.IPAddress(ipaddress.ip_address("127.0.0.1")))
        for h in hosts:
            try:
                sans.append(x509.IPAddress(ipaddress.ip_address(h)))
            except ValueError:
                sans.append(x509.DNSName(h))
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, ident.name)]))
            .issuer_name(ca_cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now)
            .not_valid_after(later)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(  # every session both listens and connects (peers), so both uses
                x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                critical=False,
            )
            .sign(ca_key, hashes.SHA256())
        )
        write_key(key, out / f"{ident.name}.key")
        (out / f"{ident.name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        written[ident.name] = out / f"{ident.name}.pem"
    return written


def _rule(rule_id: str, messages: list[str], key_exprs: list[str]) -> dict:
    return {"id": rule_id, "permission": "allow", "flows": ["ingress"], "messages": messages, "key_exprs": key_exprs}


def access_rules(keys: Keys, identities: list[Identity], role: str) -> dict:
    """Zenoh's `access_control` section for a session of `role`: what each identity may send into it.

    Outgoing messages are allowed to every known identity (they only see what they subscribed to); from an unknown
    certificate nothing is accepted and nothing is sent to it.
    """
    r = keys.root
    sim = [f"{r}/sim/{k}" for k in SIM_KEYS]
    requests = [getattr(keys, k) for k in ("goal", "cancel", "state", "map_get", "map_clear")] + [f"{r}/scene/*"]
    robot = [
        _rule("robot publishes joint states", ["put"], [keys.joint_states]),
        _rule("robot follows trajectories", ["declare_subscriber"], [keys.trajectory, keys.status]),
        _rule("robot watches the service", ["declare_liveliness_subscriber", "liveliness_query"], [keys.alive]),
    ]
    sensor = [_rule("sensors publish clouds", ["put"], [f"{r}/clouds/*"])]
    rules = {
        "service": [_rule("the service", ALL_MESSAGES, [f"{r}/**"])],
        "robot": robot,
        "sensor": sensor,
        "sim": [
            *robot,
            *sensor,
            _rule("the sim's own keys", ["put", "declare_queryable", "reply", "declare_subscriber"], sim),
        ],
        "client": [
            _rule(
                "clients request", ["query"], requests + [sim[SIM_KEYS.index("gripper")], sim[SIM_KEYS.index("state")]]
            ),
            _rule("clients read", ["declare_subscriber"], [f"{r}/**"]),
            _rule("clients watch the service", ["declare_liveliness_subscriber", "liveliness_query"], [keys.alive]),
            _rule("clients report task progress", ["put"], [f"{r}/task/progress"]),
        ],
        "router": [_rule("the router forwards", ALL_MESSAGES, [f"{r}/**"])],
    }
    if role == "router":
        del rules["router"]  # routers of one cell do not chain
    config_rules = [
        {
            "id": "send to known identities",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ALL_MESSAGES,
            "key_exprs": [f"{r}/**"],
        },
    ]
    subjects, policies = [], []
    for part, part_rules in rules.items():
        names = sorted({i.name for i in identities if i.role == part})
        if not names:
            continue
        subjects.append({"id": part, "cert_common_names": names})
        config_rules += [x for x in part_rules if x not in config_rules]
        policies.append(
            {
                "id": f"{part} policy",
                "rules": ["send to known identities"] + [x["id"] for x in part_rules],
                "subjects": [part],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": config_rules,
        "subjects": subjects,
        "policies": policies,
    }


def zenoh_config(
    certs: Path, ident: Identity, keys: Keys, identities: list[Identity], endpoint: str, via_router: bool = False
) -> dict:
    """The Zenoh config (as JSON) of one identity: mutual TLS only, access control, no scouting; `certs` is where
    its processes find the files (absolute).

    Peer to peer: the service listens on `endpoint`, the others connect to it. `via_router`: the router listens on
    it and everyone else is its client (a peer profile does the same with `--mode client --connect <endpoint>`)."""
    tls = {
        "root_ca_certificate": str(certs / "ca.pem"),
        "listen_private_key": str(certs / f"{ident.name}.key"),
        "listen_certificate": str(certs / f"{ident.name}.pem"),
        "connect_private_key": str(certs / f"{ident.name}.key"),
        "connect_certificate": str(certs / f"{ident.name}.pem"),
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }
    host = endpoint.split("/", 1)[1].rsplit(":", 1)[0]
    conf: dict = {
        "mode": "router" if ident.role == "router" else "client" if via_router else "peer",
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": ident.role != "router"}},
        "transport": {"link": {"protocols": ["tls"], "tls": tls}},
        "access_control": access_rules(keys, identities, ident.role),
    }
    if ident.role == "router" or (ident.role == "service" and not via_router):
        conf["listen"] = {"endpoints": [endpoint]}
    else:
        conf["connect"] = {
            "endpoints": [endpoint],
            # as a client of a router (--mode client): wait up to 30 s for it (processes start in any order)
            "timeout_ms": {"router": -1, "peer": -1, "client": 30000},
            "exit_on_failure": {"router": False, "peer": False, "client": True},
        }
        if not via_router:
            conf["listen"] = {"endpoints": [f"tls/{host}:0"]}
    return conf


def write_profile(
    out: Path,
    keys: Keys,
    identities: list[Identity],
    endpoint: str = "tls/127.0.0.1:7447",
    hosts: list[str] = (),
    days: int = 365,
    mount: str | None = None,
    via_router: bool = False,
) -> dict[str, Path]:
    """Certificates and one Zenoh config per identity (`out/<name>.json5`); returns the configs' paths. `mount`:
    where the processes will find `out` (e.g. /certs in containers); default: `out` itself."""
    if not endpoint.startswith("tls/") or ":" not in endpoint[4:]:
        raise ConfigError(f"--endpoint {endpoint!r}: the secure profile speaks TLS only, e.g. tls/127.0.0.1:7447")
    names = [i.name for i in identities]
    if len(set(names)) != len(names):
        raise ConfigError(f"identity names must differ: {sorted(n for n in names if names.count(n) > 1)}")
    if mount is not None and not mount.startswith("/"):
        raise ConfigError(f"--mount {mount!r}: give the absolute path where the processes find the directory")
    make_certificates(out, identities, hosts, days)
    seen_at = Path(mount) if mount else out.resolve()
    paths = {}
    for ident in identities:
        p = out / f"{ident.name}.json5"
        header = f"// replanner secure profile: identity {ident.name!r} ({ident.role}) of {keys.root}\n"
        p.write_text(
            header + json.dumps(zenoh_config(seen_at, ident, keys, identities, endpoint, via_router), indent=2) + "\n"
        )
        paths[ident.name] = p
    return paths
