//! TLS for both transports (rustls with ring): the certificate chain and key come from
//! PEM files; gRPC and REST negotiate HTTP/2 or HTTP/1.1 by ALPN. The handshakes run in
//! the connection loop ([`super::conn`]), each within a connection's slot.

use super::ServiceError;
use crate::config::TlsConfig;
use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use std::sync::Arc;
use tokio_rustls::rustls::ServerConfig;

fn config_error(what: &str, e: impl std::fmt::Display) -> ServiceError {
    ServiceError::Config(format!("TLS {what}: {e}"))
}

/// The rustls server configuration of `tls`.
pub fn server_config(tls: &TlsConfig) -> Result<Arc<ServerConfig>, ServiceError> {
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(&tls.cert)
        .map_err(|e| config_error(&format!("certificate {}", tls.cert.display()), e))?
        .collect::<Result<_, _>>()
        .map_err(|e| config_error(&format!("certificate {}", tls.cert.display()), e))?;
    if certs.is_empty() {
        return Err(config_error(
            "certificate",
            format!("{} holds no certificate", tls.cert.display()),
        ));
    }
    let key = PrivateKeyDer::from_pem_file(&tls.key)
        .map_err(|e| config_error(&format!("key {}", tls.key.display()), e))?;
    let provider = Arc::new(tokio_rustls::rustls::crypto::ring::default_provider());
    let mut config = ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| config_error("protocol versions", e))?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .map_err(|e| config_error("certificate and key", e))?;
    config.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
    Ok(Arc::new(config))
}
