"""The plumbing under every stage: output folders that morphshell owns by content.

morphshell never deletes or overwrites a file it did not make.  "Made" is decided by
content, recorded when the file is written, never after the fact:

* Every folder morphshell writes carries a stamp file, ``.morphshell-build`` (JSON), its
  manifest: for each file it wrote, the path relative to the folder, the SHA-256 and the
  size of what it wrote (``files``), and the subfolders it made (``dirs``).
* A file is morphshell's only when the manifest lists it with the hash and size it has now.
  A file the manifest does not list, or whose content changed since (a user's edit, a copy
  dropped in under the same name), is the user's: it is never deleted or overwritten, and
  the run that would do so is refused naming the file and the fix.  The same holds for
  folders: an unlisted folder (even an empty one), a symbolic link, a FIFO or a device.
* Writing into a folder in place (a stage command on a design folder, the studio's Save,
  a sweep's results) goes through :func:`.writes.atomic_file`, the one writer of the
  project: a unique temporary file beside the destination (``O_EXCL``, never following a link),
  its hash recorded in the manifest, then one atomic rename.  The manifest is updated
  under a lock on the folder, so concurrent writers never lose each other's records.
* Whole folders (a build, ``stl/``, ``report/``) are made in a private temporary folder
  (mode 0700) beside the destination, sealed (every file hashed into its manifest) and
  renamed into place (:func:`.staging.atomic_dir`, :func:`.staging.replace_dir`); the
  previous folder is moved aside and only the files its manifest vouches for are deleted.
* The temporary, moved-aside and staging folders morphshell leaves after a kill are
  recognised by the stamp inside them (what they were made for, a random token that is
  also in their name, their owner), never by their name alone; a user's
  ``.petal.tmp-notes`` or ``.petal.old-2023`` is left alone.

Only the private temporary folders are trusted as a whole: they are made with mode 0700
under a random name, and nothing but the running command writes into them.

Outputs follow the umask like ordinary files (0644 files and 0755 folders under the
usual umask 022), although the temporary files and folders are private.

The package, by concern (each module imports only those above it):

=========================  =======================================================
:mod:`.manifest`           the stamp: reading, checking and storing a folder's
                           manifest; whether a file or a private folder is ours
:mod:`.writes`             writing one file: :func:`~.writes.atomic_file`,
                           ``atomic_write_text``, ``make_dirs``, ``remove_file``
:mod:`.locks`              one build of an output folder at a time (``build_lock``)
:mod:`.ownership`          audits and claims: may this command write that folder?
:mod:`.staging`            whole folders: made in private, sealed, swapped into
                           place; a build's staging folder; recovery after a kill
:mod:`.inputs`             reading the user's input files (size-limited, no FIFOs)
=========================  =======================================================

Beside them, plumbing that imports nothing of the project:

=========================  =======================================================
:mod:`.progress`           progress lines on stderr (``say``, ``k/n`` and an ETA)
                           and their JSON events
:mod:`.records`            JSON records: the project's one encoder (``json_text``)
:mod:`.provenance`         file hashes, package versions, the lock file's record
:mod:`.child`              the command line of every child Python (``python_argv``)
:mod:`.machine`            the memory this process may still take
=========================  =======================================================
"""
