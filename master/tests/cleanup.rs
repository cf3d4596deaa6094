//! The process-wide registry of temporaries ([`texsyn::cleanup`]): what a
//! SIGINT or SIGTERM handler removes. One test, as clean-up closes the
//! registry for the whole process.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use texsyn::cleanup::{self, Temporary};
use texsyn::imaging::{self, ColorImage};

fn temp_files(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-"))
        .collect()
}

#[test]
fn clean_up_removes_temp_files_directories_and_processes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.png");
    std::fs::write(&out, b"previous result").unwrap();

    // A registered directory with a file in it.
    let tokens = dir.path().join("tokens");
    let ((), _dir_registration) = cleanup::register(
        || std::fs::create_dir(&tokens).map(|_| std::fs::write(tokens.join("token"), "t").unwrap()),
        |_| Temporary::Dir(tokens.clone()),
        || std::io::Error::other("interrupted"),
    )
    .unwrap();
    // A registered child process.
    let (mut child, _child_registration) = cleanup::register(
        || Command::new("sleep").arg("60").spawn(),
        |c| Temporary::Kill(c.id()),
        || std::io::Error::other("interrupted"),
    )
    .unwrap();

    // A large noisy image takes a while to encode: clean up while its
    // atomic save is writing the temp file.
    let (w, h) = (4096, 3072);
    let mut x = 0x2545_f491_u32;
    let rgb = (0..w * h * 3)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as u8
        })
        .collect();
    let img = ColorImage::from_vec(w, h, rgb);
    let target = out.clone();
    let save = std::thread::spawn(move || imaging::save_color(&target, &img));
    let start = Instant::now();
    while temp_files(dir.path()).is_empty() {
        assert!(
            start.elapsed() < Duration::from_secs(30) && !save.is_finished(),
            "the save never showed a temp file"
        );
        std::thread::sleep(Duration::from_micros(200));
    }
    assert!(cleanup::registered().len() >= 3);
    assert!(cleanup::clean_up() >= 3);

    assert!(temp_files(dir.path()).is_empty(), "temp file left");
    assert!(!tokens.exists(), "registered directory left");
    let status = child.wait().unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(status.signal(), Some(9), "{status:?}");
    }
    assert!(!status.success());
    let saved = save.join().unwrap();
    assert!(
        saved.is_err(),
        "the save lost its temp file, so it must fail"
    );
    assert!(temp_files(dir.path()).is_empty(), "temp file left");
    assert_eq!(std::fs::read(&out).unwrap(), b"previous result");

    // Nothing new is created once the process is ending.
    let late = dir.path().join("late.png");
    let e = imaging::save_color(&late, &ColorImage::new(2, 2)).unwrap_err();
    assert!(format!("{e:#}").contains("interrupted"), "{e:#}");
    assert!(!late.exists());
    assert!(temp_files(dir.path()).is_empty());
    assert!(cleanup::registered().is_empty());
}
