//! Services left half-created by a process killed while it created them.
//!
//! iceoryx2 writes a service's static configuration with the permissions `0600` and makes it
//! read-only (`0400`) once the service is complete. A process killed in between (the
//! watchdog's SIGKILL of a hung module) leaves the file at `0600` for good, and every later
//! open fails with `HangsInCreation` after iceoryx2's creation timeout: a restarted module can
//! then never open the channel (seen: 37 restarts of the Manager in a row on
//! `manager/status`). A file still not finalized after that timeout has no live creator, so
//! [`retry_if_hanging`] removes it and opens once more, which creates the service again.

use std::os::unix::fs::PermissionsExt as _;
use std::path::PathBuf;

use iceoryx2::prelude::ServiceName;
use iceoryx2::service::messaging_pattern::MessagingPattern;
use iceoryx2::service::service_hash::ServiceHash;

use super::Service;

/// Mode of a static configuration iceoryx2 is still writing.
const IN_CREATION_MODE: u32 = 0o600;

/// The file holding the static configuration of service `name` with `pattern`.
pub(super) fn static_config_path(
    config: &iceoryx2::config::Config,
    name: &ServiceName,
    pattern: MessagingPattern,
) -> PathBuf {
    let hash = ServiceHash::new::<<Service as iceoryx2::service::Service>::ServiceNameHasher>(
        name, pattern,
    );
    let g = &config.global;
    PathBuf::from(g.service_dir().to_string()).join(format!(
        "{}{}{}",
        g.prefix,
        hash.as_str(),
        g.service.static_config_storage_suffix
    ))
}

/// Removes the static configuration of `name` if it is still being created although
/// iceoryx2's creation timeout has passed since it was last written; true if removed.
pub(super) fn remove_half_created(
    config: &iceoryx2::config::Config,
    name: &ServiceName,
    pattern: MessagingPattern,
) -> bool {
    let path = static_config_path(config, name, pattern);
    let Ok(meta) = std::fs::metadata(&path) else {
        return false;
    };
    let age = meta.modified().ok().and_then(|m| m.elapsed().ok());
    if meta.permissions().mode() & 0o777 != IN_CREATION_MODE
        || age.is_none_or(|a| a < config.global.creation_timeout)
    {
        return false;
    }
    match std::fs::remove_file(&path) {
        Ok(()) => {
            tracing::warn!(
                service = %name,
                file = %path.display(),
                "service left half-created (its creator was killed): removed, creating it again"
            );
            true
        }
        Err(e) => {
            tracing::warn!(service = %name, file = %path.display(), "half-created service: {e}");
            false
        }
    }
}

/// Runs `open`; when it fails because the service hangs in creation (`is_hanging`) and the
/// half-created service could be removed, runs it once more.
pub(super) fn retry_if_hanging<T, E>(
    config: &iceoryx2::config::Config,
    name: &ServiceName,
    pattern: MessagingPattern,
    is_hanging: impl Fn(&E) -> bool,
    mut open: impl FnMut() -> Result<T, E>,
) -> Result<T, E> {
    match open() {
        Err(e) if is_hanging(&e) && remove_half_created(config, name, pattern) => open(),
        r => r,
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, SystemTime};

    use super::*;
    use crate::channel::{Node, NodeOptions};
    use crate::msg::Twist;
    use crate::shm;

    /// What a process killed while creating the service leaves: its static configuration,
    /// still writable, last written `age` ago.
    fn leave_half_created(path: &std::path::Path, age: Duration) {
        std::fs::create_dir_all(path.parent().expect("service folder")).expect("folder");
        let f = std::fs::File::create(path).expect("static config");
        f.set_permissions(std::fs::Permissions::from_mode(IN_CREATION_MODE))
            .expect("mode");
        f.set_modified(SystemTime::now() - age).expect("mtime");
    }

    #[test]
    fn a_channel_left_half_created_by_a_killed_process_opens_again() {
        let prefix = shm::unique_prefix("hanging");
        let node = Node::new(NodeOptions::new("t").prefix(&prefix)).expect("node");
        let config = node.iceoryx_config().clone();
        let channel = "manager/status";
        let name = ServiceName::new(channel).expect("name");
        let events = static_config_path(&config, &name, MessagingPattern::Event);
        let data = static_config_path(&config, &name, MessagingPattern::PublishSubscribe);
        assert_ne!(events, data);

        // Being created right now by a live process: left alone.
        leave_half_created(&data, Duration::ZERO);
        assert!(!remove_half_created(
            &config,
            &name,
            MessagingPattern::PublishSubscribe
        ));
        assert!(data.exists());

        // Abandoned: both the data and the event service hang in creation.
        let old = config.global.creation_timeout + Duration::from_secs(5);
        leave_half_created(&data, old);
        leave_half_created(&events, old);
        let publisher = node.publisher::<Twist>(channel);
        let subscriber = node.subscriber::<Twist>(channel);
        let (publisher, subscriber) = (publisher.expect("publisher"), subscriber.expect("sub"));
        publisher.publish(Twist::default()).expect("publish");
        assert!(subscriber.receive().expect("receive").is_some());
        let mode = std::fs::metadata(&data)
            .expect("created again")
            .permissions()
            .mode();
        assert_ne!(mode & 0o777, IN_CREATION_MODE, "a complete service now");
        drop((publisher, subscriber, node));
        shm::remove_prefix_files(&prefix);
    }
}
