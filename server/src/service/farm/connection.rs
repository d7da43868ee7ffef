//! One process's connection to the farm: the NATS client, its JetStream context, and the
//! stream, KV buckets and object stores named in [`super`], created on first use by whichever
//! process connects first (creation is idempotent: same configuration, same result).
//!
//! Invariants:
//! - The work stream has work-queue retention: a message is removed once acked, and its two
//!   consumers filter disjoint subjects (bakes, units), as JetStream requires of a work queue.
//! - Both consumers ack explicitly with a short [`ACK_WAIT`], so a message whose worker died is
//!   delivered again within seconds; long work sends progress acks every [`PROGRESS_ACK_EVERY`].
//! - [`Farm::block_on`] is how the blocking service traits reach the async client: on a
//!   multi-thread runtime's worker it steps out with `block_in_place` (the runtime's other
//!   workers keep the client's connection task running, so it cannot deadlock on itself); on a
//!   `spawn_blocking` or plain thread it simply blocks on the runtime handle.

use std::future::Future;
use std::time::Duration;

use async_nats::jetstream::{self, consumer, kv, object_store, stream};

use super::*;

/// How long a delivered message may go without an ack or a progress ack before JetStream
/// delivers it to another worker.
pub const ACK_WAIT: Duration = Duration::from_secs(10);
/// How often long work extends its message's ack deadline.
pub const PROGRESS_ACK_EVERY: Duration = Duration::from_secs(3);

/// The farm as one process sees it.
pub struct Farm {
    pub client: async_nats::Client,
    pub jetstream: jetstream::Context,
    pub work: stream::Stream,
    pub jobs: kv::Store,
    pub units: kv::Store,
    pub owners: kv::Store,
    pub blobs: object_store::ObjectStore,
    pub operators: object_store::ObjectStore,
    /// The runtime the client's connection runs on (for [`Farm::block_on`]).
    pub runtime: tokio::runtime::Handle,
}

async fn key_value(js: &jetstream::Context, bucket: &str) -> Result<kv::Store, FarmError> {
    if let Ok(store) = js.get_key_value(bucket).await {
        return Ok(store);
    }
    // The bucket's stream as `create_key_value` would make it. Not through `create_key_value`
    // itself: it first reads the account info, whose 2.9-server form async-nats 0.51 does not
    // parse.
    js.get_or_create_stream(stream::Config {
        name: format!("KV_{bucket}"),
        subjects: vec![format!("$KV.{bucket}.>")],
        max_messages_per_subject: 1,
        max_message_size: -1,
        storage: stream::StorageType::File,
        allow_rollup: true,
        deny_delete: true,
        allow_direct: true,
        num_replicas: 1,
        discard: stream::DiscardPolicy::New,
        duplicate_window: Duration::from_secs(120),
        ..Default::default()
    })
    .await
    .map_err(|e| FarmError::nats(format!("KV bucket {bucket}"), e))?;
    js.get_key_value(bucket)
        .await
        .map_err(|e| FarmError::nats(format!("KV bucket {bucket}"), e))
}

async fn objects(
    js: &jetstream::Context,
    bucket: &str,
) -> Result<object_store::ObjectStore, FarmError> {
    if let Ok(store) = js.get_object_store(bucket).await {
        return Ok(store);
    }
    js.create_object_store(object_store::Config {
        bucket: bucket.to_string(),
        storage: stream::StorageType::File,
        ..Default::default()
    })
    .await
    .map_err(|e| FarmError::nats(format!("object store {bucket}"), e))
}

/// The pull consumer of one subject of the work stream.
pub fn consumer_config(name: &str, subject: &str) -> consumer::pull::Config {
    consumer::pull::Config {
        durable_name: Some(name.to_string()),
        filter_subject: subject.to_string(),
        ack_policy: consumer::AckPolicy::Explicit,
        ack_wait: ACK_WAIT,
        max_deliver: -1,
        ..Default::default()
    }
}

impl Farm {
    /// Connects to `url` (`nats://HOST:PORT`) and opens (creating if absent) everything the farm
    /// uses. Must be called on a multi-thread tokio runtime.
    pub async fn connect(url: &str) -> Result<Farm, FarmError> {
        let client = async_nats::ConnectOptions::new()
            .name("lightfarm")
            .retry_on_initial_connect()
            .connect(url)
            .await
            .map_err(|e| FarmError::nats(format!("connect to {url}"), e))?;
        let js = jetstream::new(client.clone());
        let work = js
            .get_or_create_stream(stream::Config {
                name: WORK_STREAM.to_string(),
                subjects: vec![BAKE_SUBJECT.to_string(), UNIT_SUBJECT.to_string()],
                retention: stream::RetentionPolicy::WorkQueue,
                storage: stream::StorageType::File,
                duplicate_window: Duration::from_secs(120),
                ..Default::default()
            })
            .await
            .map_err(|e| FarmError::nats(format!("stream {WORK_STREAM}"), e))?;
        for (name, subject) in [
            (COORDINATOR_CONSUMER, BAKE_SUBJECT),
            (UNIT_CONSUMER, UNIT_SUBJECT),
        ] {
            work.get_or_create_consumer(name, consumer_config(name, subject))
                .await
                .map_err(|e| FarmError::nats(format!("consumer {name}"), e))?;
        }
        Ok(Farm {
            jobs: key_value(&js, JOBS_BUCKET).await?,
            units: key_value(&js, UNITS_BUCKET).await?,
            owners: key_value(&js, OWNERS_BUCKET).await?,
            blobs: objects(&js, BLOBS_BUCKET).await?,
            operators: objects(&js, OPERATORS_BUCKET).await?,
            client,
            jetstream: js,
            work,
            runtime: tokio::runtime::Handle::current(),
        })
    }

    /// The pull consumer named `name` on the work stream.
    pub async fn consumer(
        &self,
        name: &str,
    ) -> Result<consumer::Consumer<consumer::pull::Config>, FarmError> {
        self.work
            .get_consumer(name)
            .await
            .map_err(|e| FarmError::nats(format!("consumer {name}"), e))
    }

    /// Runs `future` to completion from synchronous code (see the module doc).
    pub fn block_on<F: Future>(&self, future: F) -> F::Output {
        match tokio::runtime::Handle::try_current() {
            Ok(_) => tokio::task::block_in_place(|| self.runtime.block_on(future)),
            Err(_) => self.runtime.block_on(future),
        }
    }
}
